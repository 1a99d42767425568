"""The MAVLink camera with video: a station finds the stream to show in
``VIDEO_STREAM_INFORMATION`` and plays it with PyAV (RTSP from GStreamer's server, RTP/UDP on
the port it is told to listen on), and tracks on every kind of stream: the service's H.264
frames with or without a declared size, CDR ``CompressedVideo`` units on the video key, with
the real picture size read from the stream's keyframes."""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import av
import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

pytest.importorskip("zenoh")

import zenoh

from arcf.adapters.ingest import Ingest, parse_source, rtp_sdp
from arcf.adapters.mavlink import CameraConfig, MavlinkCameras, VideoStream
from arcf.client import TrackingClient
from arcf.client.foxglove import compressed_video
from arcf.client.media.images import decode_compressed
from arcf.loadtools.groundstation import GroundStation
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.senders import (
    RtspServer,
    VideoSender,
    free_rtp_port,
    rtsp_server_problem,
    write_video_file,
)
from arcf.loadtools.video import encode_video
from arcf.loadtools.waiting import wait_until

mav = mavutil.mavlink
COMP = 100
N, GOP = 30, 10


def test_video_streams_as_mavlink_names_them() -> None:
    rtsp = VideoStream.parse("rtsp://192.168.144.25:8554/main.264")
    assert (rtsp.kind, rtsp.uri) == (mav.VIDEO_STREAM_TYPE_RTSP,
                                     "rtsp://192.168.144.25:8554/main.264")
    # UDP: the port the station listens on, as the message's definition says
    assert VideoStream.parse("rtp://:5600") == VideoStream(mav.VIDEO_STREAM_TYPE_RTPUDP, "5600")
    assert VideoStream.parse("udp://0.0.0.0:5601") == VideoStream(
        mav.VIDEO_STREAM_TYPE_MPEG_TS, "5601")
    for bad in ("http://x/y", "rtp://:0", "udp://host", "rtsp://" + "x" * 160):
        with pytest.raises(ValueError):
            VideoStream.parse(bad)


@pytest.fixture(scope="module")
def camera(wakeboard7):
    images = [decode_compressed(p.read_bytes()) for p in wakeboard7.frames[:N]]
    units = encode_video(images, "h264", fps=30, gop=GOP, repeat_headers=True)
    return wakeboard7, units, (images[0].shape[1], images[0].shape[0])


def _uri(info: Any) -> str:
    raw = info.uri if isinstance(info.uri, bytes) else str(info.uri).encode()
    return raw.rstrip(b"\0").decode()


def test_a_station_plays_the_advertised_udp_stream(offline_client: Any, camera) -> None:
    """RTP over UDP: the camera advertises the port, the station listens there (an SDP of
    its own, as QGroundControl's receiver has) and decodes what the camera's sender sends."""
    _, units, size = camera
    video_port = free_rtp_port()
    port = free_port()
    endpoint = MavlinkCameras(offline_client, f"udpin:127.0.0.1:{port}",
                              [CameraConfig("cam", COMP, VideoStream.parse(
                                  f"rtp://:{video_port}"))],
                              status_interval_s=0.0).start()
    station = GroundStation(port, COMP)
    try:
        wait_until(lambda: endpoint.link_up, timeout=30, what="the station heard")
        camera_info = station.request(mav.MAVLINK_MSG_ID_CAMERA_INFORMATION)
        assert camera_info.flags & mav.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        info = station.request(mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 0)
        assert (info.stream_id, info.count, info.type) == (1, 1, mav.VIDEO_STREAM_TYPE_RTPUDP)
        assert not info.flags & mav.VIDEO_STREAM_STATUS_FLAGS_RUNNING  # no frames yet
        # NaN, as MAVSDK sends it, means all streams too; a stream the camera has not, denied
        assert station.request(mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, math.nan).uri == \
            info.uri
        result, texts = station.command(mav.MAV_CMD_REQUEST_MESSAGE,
                                        mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 2)
        assert result == mav.MAV_RESULT_DENIED and "no video stream 2" in texts, texts
        listen = int(_uri(info))
        assert listen == video_port
        sdp = Path(f"/tmp/arcf-station-{os.getpid()}.sdp")
        sdp.write_text(rtp_sdp("127.0.0.1", listen))
        sender = VideoSender(units, f"rtp://127.0.0.1:{listen}", "rtp", size, repeat=3).start()
        try:
            with av.open(str(sdp), format="sdp", timeout=(20, 10),
                         options={"protocol_whitelist": "file,udp,rtp"}) as player:
                pictures = []
                for frame in player.decode(video=0):
                    pictures.append((frame.width, frame.height))
                    if len(pictures) == 5:
                        break
        finally:
            sender.stop()
            sdp.unlink()
        assert pictures == [size] * 5
    finally:
        station.close()
        endpoint.close()


@pytest.fixture(scope="module")
def service():
    svc = ServiceProcess(workers=1)
    yield svc
    assert svc.stop() == 0


def _track_rectangle(station: GroundStation, box: Any, size: tuple[int, int]) -> None:
    x, y, w, h = box
    W, H = size
    result, texts = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, (x - 1) / W,
                                    (y - 1) / H, (x - 1 + w) / W, (y - 1 + h) / H)
    assert result == mav.MAV_RESULT_ACCEPTED, texts


def _active(station: GroundStation, since: float, n: int = 3) -> list[Any]:
    def active() -> list[Any]:
        return [s for s in station.since(since, "CAMERA_TRACKING_IMAGE_STATUS")
                if s.tracking_status & mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
                and np.isfinite(s.rec_top_x)]  # a box of the service's (not: on its way)
    wait_until(lambda: len(active()) >= n, timeout=60, what=f"{n} ACTIVE statuses with a box")
    return active()


def test_a_station_plays_the_advertised_rtsp_stream_and_tracks_on_it(service, camera,
                                                                     tmp_path) -> None:
    """A camera's RTSP server (GStreamer's), ``arcf-ingest`` from it into the service, the
    MAVLink camera advertising that RTSP URI: the station reads it, plays it with PyAV, and
    tracks with a rectangle on the stream's real size."""
    problem = rtsp_server_problem()
    if problem is not None:
        pytest.skip(problem)
    seq, units, size = camera
    ts = write_video_file(units * 4, tmp_path / "cam.ts", size)  # 4 s, keyframes each 1/3 s
    port = free_port()
    with RtspServer(ts, free_port()) as server, \
            TrackingClient(connect=[service.endpoint]) as client:
        ingest = Ingest(client, parse_source(server.url), "gimbal").start()
        endpoint = MavlinkCameras(client, f"udpin:127.0.0.1:{port}",
                                  [CameraConfig("gimbal", COMP, VideoStream.parse(server.url))],
                                  status_interval_s=0.1).start()
        station = GroundStation(port, COMP)
        try:
            wait_until(lambda: endpoint.link_up and endpoint.cameras[0].last_frame is not None,
                       timeout=60, what="the station heard and frames flowing")
            info = station.request(mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 1)
            assert info.type == mav.VIDEO_STREAM_TYPE_RTSP and _uri(info) == server.url
            assert info.flags & mav.VIDEO_STREAM_STATUS_FLAGS_RUNNING
            assert (info.resolution_h, info.resolution_v) == size
            assert info.encoding == mav.VIDEO_STREAM_ENCODING_H264
            status = station.request(mav.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS, 0)
            assert (status.resolution_h, status.resolution_v) == size
            with av.open(_uri(info), options={"rtsp_transport": "tcp"},
                         timeout=(20, 10)) as player:
                shown = [(f.width, f.height) for f, _ in zip(player.decode(video=0),
                                                             range(3), strict=False)]
            assert shown == [size] * 3
            camera_info = station.request(mav.MAVLINK_MSG_ID_CAMERA_INFORMATION)
            assert (camera_info.resolution_h, camera_info.resolution_v) == size
            t0 = time.monotonic()
            _track_rectangle(station, seq.groundtruth[0], size)
            _active(station, t0)
        finally:
            station.close()
            endpoint.close()
            ingest.close()


@pytest.fixture
def video_rig(service) -> Iterator[dict[str, Any]]:
    port = free_port()
    client = TrackingClient(connect=[service.endpoint], frame_congestion="block")
    endpoint = MavlinkCameras(client, f"udpin:127.0.0.1:{port}",
                              [CameraConfig("fox", COMP), CameraConfig("sdk", COMP + 1)],
                              status_interval_s=0.1).start()
    yield {"client": client, "endpoint": endpoint, "port": port}
    endpoint.close()
    client.close()


@pytest.mark.parametrize("convention", ["compressed_video", "frame"])
def test_video_streams_are_cameras_with_their_real_size(video_rig, camera,
                                                        convention: str) -> None:
    """H.264 that declares no size, on the video key (CompressedVideo) or as the service's
    own frames: the camera reads the size from the keyframes, says it, and tracks."""
    seq, units, size = camera
    client, endpoint = video_rig["client"], video_rig["endpoint"]
    stream, component = ("fox", COMP) if convention == "compressed_video" else ("sdk", COMP + 1)
    pub = client.session.declare_publisher(f"video/{stream}/stream",
                                           congestion_control=zenoh.CongestionControl.BLOCK)
    stop = threading.Event()

    def camera_loop() -> None:
        for i in range(900):  # bounded: 90 s at 10 fps
            if stop.wait(0.1):  # the stimulus: a 10 fps camera
                return
            unit = units[i % len(units)]
            if convention == "compressed_video":
                pub.put(compressed_video(unit, "h264", time.time_ns()))
            else:
                client.publish_frame(stream, data=unit, encoding="h264", seq=i)

    thread = threading.Thread(target=camera_loop, daemon=True)
    thread.start()
    station = GroundStation(video_rig["port"], component)
    try:
        cam = endpoint.cameras[0 if convention == "compressed_video" else 1]
        wait_until(lambda: endpoint.link_up and cam.last_frame is not None, timeout=30,
                   what="frames seen")
        assert cam.last_frame.width is None  # nothing declared: read from the keyframes
        wait_until(lambda: cam.video_size is not None and cam.video_size.read() is not None,
                   timeout=30, what="a keyframe with its parameter sets")
        info = station.request(mav.MAVLINK_MSG_ID_CAMERA_INFORMATION)
        assert (info.resolution_h, info.resolution_v) == size
        assert not info.flags & mav.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM  # none configured
        t0 = time.monotonic()
        result, texts = station.command(mav.MAV_CMD_REQUEST_MESSAGE,
                                        mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION)
        assert result == mav.MAV_RESULT_DENIED and any("no video stream" in t for t in texts)
        _track_rectangle(station, seq.groundtruth[0], size)
        statuses = _active(station, t0)
        s = statuses[-1]
        assert 0.0 <= s.rec_top_x < s.rec_bottom_x <= 1.0  # a box within the picture
        assert np.isfinite([s.point_x, s.point_y]).all()
    finally:
        stop.set()
        thread.join(timeout=5)
        station.close()
        pub.undeclare()
