"""The MAVLink camera endpoint against a real service, driven by a ground station played with
pymavlink over UDP on loopback: capability discovery, rectangle and point tracking on a real
sequence, status at the requested rate with the service's boxes, stop, denials, a lost link,
a stream that stops (the status leaves ACTIVE, and comes back with the frames)."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from arcf.adapters.mavlink import (
    TARGET_DATA_NONE,
    CameraConfig,
    MavlinkCameras,
    point_box,
    rectangle_box,
    tracking_status,
)
from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.loadtools.groundstation import GroundStation
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.waiting import wait_until
from arcf.schemas import Result

mav = mavutil.mavlink
pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

STREAM, COMP = "cam1", 100


def test_normalised_coordinates_become_boxes() -> None:
    b = rectangle_box(0.25, 0.5, 0.75, 1.0, (1280, 720))
    assert (b.x, b.y, b.w, b.h) == (321.0, 361.0, 640.0, 360.0)
    p = point_box(0.5, 0.5, 0.05, (1280, 720))  # radius: a share of the width
    assert (p.x, p.y, p.w, p.h) == (577.0, 297.0, 128.0, 128.0)
    edge = point_box(0.0, 0.0, 0.05, (1280, 720))  # cut to the frame
    assert (edge.x, edge.y, edge.w, edge.h) == (1.0, 1.0, 64.0, 64.0)


def _result(status: str, seq: int, **extra: Any) -> Result:
    nan = float("nan")
    boxed = status not in ("stale", "stopped")
    return Result(session_id="s1", stream_id=STREAM, frame_seq=seq, capture_ts_ns=1,
                  box=[321.0, 181.0, 64.0, 36.0] if boxed else [nan] * 4,
                  peak=0.5, psr=9.0, aberrance=0.01, aberrance_release=0.01, scale=1.0,
                  status=status, dropped=0, received_ts_ns=1, decode_s=0.0, track_s=0.0,
                  published_ts_ns=1, **extra)


def test_a_stale_session_is_never_active_whoever_says_so(offline_client: Any) -> None:
    """The service's stale notice, and silence from the service (the adapter's own timeout,
    on a clock given to it), both make the status ERROR without a box; a result about a
    frame makes it ACTIVE again. The STATUSTEXT is sent once per change."""
    assert tracking_status(_result("stale", 4, code="no_frames")) == \
        mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR
    client = offline_client
    endpoint = MavlinkCameras(client, f"udpin:127.0.0.1:{free_port()}",  # type: ignore[arg-type]
                              [CameraConfig(STREAM, COMP)], stale_after_s=1.0)
    try:
        (cam,) = endpoint.cameras
        cam.session_id, cam.mode = "s1", mav.CAMERA_TRACKING_MODE_RECTANGLE
        cam.last_frame = SimpleNamespace(width=1280, height=720)  # type: ignore[assignment]
        seen = client.callbacks["results"]
        seen(_result("tracking", 3, track_state="tracking", confidence=0.9))
        t = cam.heard_at
        fresh = endpoint._status(cam, t + 0.5)
        assert fresh.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
        assert fresh.target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS
        assert fresh.rec_top_x == pytest.approx(320 / 1280)

        def no_box(status: Any) -> bool:
            return (status.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR
                    and status.target_data == TARGET_DATA_NONE
                    and status.tracking_mode == mav.CAMERA_TRACKING_MODE_RECTANGLE
                    and all(np.isnan([status.point_x, status.rec_top_x, status.rec_bottom_y])))

        # the service says the stream stopped: at once, whatever the clock
        seen(_result("stale", 3, code="no_frames", message="no frame of stream 'cam1' for 1 s"))
        assert no_box(endpoint._status(cam, cam.heard_at))
        endpoint._tick(cam.heard_at)
        endpoint._tick(cam.heard_at + 0.1)
        assert endpoint.counts["stale"] == 1  # told once
        # frames again: active
        seen(_result("tracking", 9, track_state="tracking", confidence=0.9))
        endpoint._tick(cam.heard_at)
        assert endpoint._status(cam, cam.heard_at).tracking_status == \
            mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
        assert endpoint.counts["stale_ended"] == 1
        # nothing at all from the service (gone): stale after stale_after_s, not before
        t = cam.heard_at
        assert endpoint._status(cam, t + 0.9).tracking_status == \
            mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
        assert no_box(endpoint._status(cam, t + 1.1))
        # whose silence: the camera's, when this camera saw no frame either; else the service's
        assert "no frame from the camera" in (endpoint.stale(cam, t + 1.1) or "")
        cam.frame_at = t + 1.0
        assert "no result from the tracking service" in (endpoint.stale(cam, t + 1.1) or "")
        # no session: idle, never stale
        cam.session_id, cam.result = None, None
        assert endpoint.stale(cam, t + 100) is None
        assert endpoint._status(cam, t + 100).tracking_status == \
            mav.CAMERA_TRACKING_STATUS_FLAGS_IDLE
    finally:
        endpoint.close()
    with pytest.raises(ValueError, match="stale_after_s"):
        MavlinkCameras(offline_client, f"udpin:127.0.0.1:{free_port()}",  # type: ignore[arg-type]
                       [CameraConfig(STREAM, COMP)], stale_after_s=float("nan"))


def test_every_error_says_why_once(monkeypatch: pytest.MonkeyPatch,
                                   offline_client: Any) -> None:
    """An error result (a picture not decoded, a video waiting for its keyframe) and a lost
    target make the status ERROR: each is told in a STATUSTEXT when it starts, once, and
    its end once; an ended session says why it ended."""
    client = offline_client
    endpoint = MavlinkCameras(client, f"udpin:127.0.0.1:{free_port()}",  # type: ignore[arg-type]
                              [CameraConfig(STREAM, COMP)], status_interval_s=60.0)
    sent: list[Any] = []
    monkeypatch.setattr(endpoint, "_send", lambda cam, m: sent.append(m)
                        if m.get_type() == "STATUSTEXT" else None)
    try:
        (cam,) = endpoint.cameras
        cam.session_id, cam.mode = "s1", mav.CAMERA_TRACKING_MODE_RECTANGLE
        seen = client.callbacks["results"]
        for seq in (1, 2):  # each names its frame; told once
            seen(_result("error", seq, code="decode_error",
                         message=f"video unit {seq}: waiting for a keyframe"))
        waiting = "video unit 1: waiting for a keyframe"
        seen(_result("tracking", 3, track_state="tracking", confidence=0.9))
        for seq in (4, 5):
            seen(_result("tracking", seq, track_state="lost", confidence=0.1))
        seen(_result("tracking", 6, track_state="coasting", confidence=0.4))
        seen(_result("stopped", 6, code="session_expired", message="no frame for 30 s"))
        texts: list[str] = []  # chunks of one text (MAVLink 2: the same id) joined
        for i, m in enumerate(sent):
            if m.id and i and sent[i - 1].id == m.id:
                texts[-1] += m.text
            else:
                texts.append(m.text)
        assert texts == [f"tracking error: {waiting}", "tracking again", "target lost",
                         "target tracked again",
                         "tracking ended (session_expired): no frame for 30 s"]
        assert cam.session_id is None
    finally:
        endpoint.close()


def test_the_status_goes_out_as_soon_as_the_session_goes_stale_or_comes_back(
        monkeypatch: pytest.MonkeyPatch, offline_client: Any) -> None:
    """A change between stale and not stale sends its STATUSTEXT and the status at once,
    not at the status's next interval: on the service's notice as it arrives (no tick of
    the I/O loop runs here), on the first result about a frame after it, and on the tick
    that finds the adapter's own timeout passed. Once per change; a station that turned
    the status off gets the STATUSTEXT only."""
    client = offline_client
    endpoint = MavlinkCameras(client, f"udpin:127.0.0.1:{free_port()}",  # type: ignore[arg-type]
                              [CameraConfig(STREAM, COMP)], status_interval_s=60.0)
    sent: list[Any] = []
    monkeypatch.setattr(endpoint, "_send", lambda cam, message: sent.append(message))

    def kinds() -> list[str]:
        return [m.get_type() for m in sent]

    try:
        assert endpoint.stale_after_s == 0.8  # the default, as the service's
        (cam,) = endpoint.cameras
        cam.session_id, cam.mode = "s1", mav.CAMERA_TRACKING_MODE_RECTANGLE
        cam.last_frame = SimpleNamespace(width=1280, height=720)  # type: ignore[assignment]
        seen = client.callbacks["results"]
        seen(_result("tracking", 3, track_state="tracking", confidence=0.9))
        assert sent == []  # no change: the status waits for its interval
        # the service's notice: the status leaves ACTIVE as it arrives
        seen(_result("stale", 3, code="no_frames", message="no frame of stream 'cam1'"))
        assert kinds() == ["STATUSTEXT", "CAMERA_TRACKING_IMAGE_STATUS"]
        assert _no_box(sent[-1])
        sent.clear()
        seen(_result("stale", 3, code="no_frames", message="no frame of stream 'cam1'"))
        assert sent == []  # the notice repeated: told once
        # a result about a frame: ACTIVE again at once, with its box
        seen(_result("tracking", 9, track_state="tracking", confidence=0.9))
        assert kinds() == ["STATUSTEXT", "CAMERA_TRACKING_IMAGE_STATUS"]
        assert sent[-1].tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
        assert sent[-1].target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS
        assert (endpoint.counts["stale"], endpoint.counts["stale_ended"]) == (1, 1)
        # the adapter's own timeout (a clock given to the tick), the next status a minute off
        sent.clear()
        t = cam.heard_at
        cam.next_status = t + 60.0
        endpoint._tick(t + 0.7)
        assert "CAMERA_TRACKING_IMAGE_STATUS" not in kinds()  # not stale yet, not due
        endpoint._tick(t + 0.9)
        statuses = [m for m in sent if m.get_type() == "CAMERA_TRACKING_IMAGE_STATUS"]
        assert len(statuses) == 1 and _no_box(statuses[0])
        assert endpoint.counts["stale"] == 2
        # the station turned the status off (interval -1): the STATUSTEXT only
        seen(_result("tracking", 10, track_state="tracking", confidence=0.9))
        cam.status_interval_s = 0.0
        sent.clear()
        seen(_result("stale", 10, code="no_frames", message="no frame of stream 'cam1'"))
        assert kinds() == ["STATUSTEXT"]
    finally:
        endpoint.close()


@pytest.fixture
def rig(wakeboard7: Any) -> Iterator[dict[str, Any]]:
    """A service, a station publishing the sequence's JPEG frames at 10 fps (looped, seq
    increasing) while ``publishing`` is set, the MAVLink endpoint on a loopback UDP port and a
    MAVLink ground station."""
    service = ServiceProcess(workers=1)
    port = free_port()
    publisher = TrackingClient(connect=[service.endpoint], frame_congestion="block")
    endpoint_client = TrackingClient(connect=[service.endpoint])
    endpoint = MavlinkCameras(endpoint_client, f"udpin:127.0.0.1:{port}",
                              [CameraConfig(STREAM, COMP)], link_timeout_s=1.0,
                              status_interval_s=1.0).start()
    station = GroundStation(port, COMP)
    sequence = wakeboard7
    data = [p.read_bytes() for p in sequence.frames]
    publishing = threading.Event()
    stop = threading.Event()
    sent: list[int] = []

    def publish() -> None:
        for seq in range(600):  # bounded: 60 s at 10 fps
            publishing.wait()  # cleared: the stream pauses
            if stop.is_set():
                return
            publisher.publish_frame(STREAM, data=data[seq % len(data)], seq=seq)
            sent.append(seq)
            time.sleep(0.1)  # the stimulus: a 10 fps camera

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        yield {"service": service, "endpoint": endpoint, "station": station,
               "client": publisher, "publishing": publishing, "sent": sent,
               "gt": np.asarray(sequence.groundtruth), "n": len(data), "port": port}
    finally:
        stop.set()
        publishing.set()
        thread.join(timeout=5)
        station.close()
        endpoint.close()
        endpoint_client.close()
        publisher.close()
        assert service.stop() == 0


def _no_box(status: Any) -> bool:
    """A stale camera's status: ERROR, no target data, NaN coordinates."""
    return (status.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR
            and status.target_data == TARGET_DATA_NONE
            and all(np.isnan([status.point_x, status.rec_top_x, status.rec_bottom_y])))


def _wait(predicate: Any, timeout: float = 30.0) -> None:
    wait_until(predicate, timeout=timeout, what="the MAVLink rig's condition")


def test_a_ground_station_tracks_through_the_mavlink_camera(rig: dict[str, Any]) -> None:
    station, endpoint, client = rig["station"], rig["endpoint"], rig["client"]
    _wait(lambda: endpoint.link_up)  # the station's heartbeat was seen

    # no frame yet: denied, saying why
    result, texts = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0.4, 0.4, 0.6, 0.6)
    assert result == mav.MAV_RESULT_DENIED and any("no frames" in t for t in texts)

    # the camera's information before its first frame: no size yet; once frames come, the
    # station hears the size without asking again
    t0 = time.monotonic()
    first = station.request(mav.MAVLINK_MSG_ID_CAMERA_INFORMATION)
    assert (first.resolution_h, first.resolution_v) == (0, 0)

    results: list = []
    sub = client.results(STREAM, callback=results.append)
    rig["publishing"].set()
    _wait(lambda: endpoint.cameras[0].last_frame is not None)
    _wait(lambda: [i for i in station.since(t0, "CAMERA_INFORMATION")
                   if (i.resolution_h, i.resolution_v) == (1280, 720)])
    told = station.since(t0, "CAMERA_INFORMATION")
    assert len(told) == 2, told  # once asked, once on the new size

    # capability discovery: a tracking camera with the stream's resolution
    info = station.request(mav.MAVLINK_MSG_ID_CAMERA_INFORMATION)
    assert info.flags & mav.CAMERA_CAP_FLAGS_HAS_TRACKING_RECTANGLE
    assert info.flags & mav.CAMERA_CAP_FLAGS_HAS_TRACKING_POINT
    assert info.get_srcComponent() == COMP
    assert (info.resolution_h, info.resolution_v) == (1280, 720)
    assert bytes(info.model_name).rstrip(b"\0").decode().endswith(STREAM)
    # heartbeats name a camera
    _wait(lambda: [h for h in station.since(0, "HEARTBEAT") if h.get_srcComponent() == COMP])
    beats = [h for h in station.since(0, "HEARTBEAT") if h.get_srcComponent() == COMP]
    assert beats[-1].type == mav.MAV_TYPE_CAMERA

    # status at 5 Hz, as asked
    result, _ = station.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL,
                                mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS, 200_000)
    assert result == mav.MAV_RESULT_ACCEPTED

    # track the target's ground-truth rectangle on the current frame
    seq = endpoint.cameras[0].last_frame.seq
    x, y, w, h = rig["gt"][seq % rig["n"]]
    W, H = 1280, 720
    result, _ = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, (x - 1) / W, (y - 1) / H,
                                (x - 1 + w) / W, (y - 1 + h) / H)
    assert result == mav.MAV_RESULT_ACCEPTED
    session = endpoint.cameras[0].session_id
    assert session is not None
    assert endpoint.cameras[0].status_interval_s == pytest.approx(0.2)  # as asked
    _wait(lambda: any(r.session_id == session and r.track_state is not None
                      for r in list(results)))  # tracking

    def statuses(since: float) -> list[Any]:
        return [s for s in station.since(since, "CAMERA_TRACKING_IMAGE_STATUS")
                if s.get_srcComponent() == COMP]

    t0 = time.monotonic()
    _wait(lambda: len(statuses(t0)) >= 10)
    status = statuses(t0)
    # never faster than asked: one per 0.2 s, and after a stall at most a second's catch-up
    # (how close to 5 Hz a loaded machine keeps is its own figure)
    assert len(status) <= (time.monotonic() - t0) / 0.2 + 6, len(status)
    assert all(s.tracking_mode == mav.CAMERA_TRACKING_MODE_RECTANGLE for s in status)
    assert all(s.tracking_status & mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
               or s.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR for s in status)
    boxed = [s for s in status if s.target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS]
    # without a box: a stale one (no result for stale_after_s: a stalled machine), or one sent
    # before the adapter had the session's first result; never target data without a box
    assert all(_no_box(s) or (s.target_data == TARGET_DATA_NONE and np.isnan(s.rec_top_x))
               for s in status if s.target_data != mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS)
    assert all(np.isfinite([s.rec_top_x, s.rec_bottom_y]).all() for s in status
               if s.target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS)
    assert boxed
    # each status's rectangle is one of the session's published boxes (float32 on the wire)
    boxes = np.array([r.box for r in list(results) if r.session_id == session
                      and r.track_state is not None])
    for s in boxed:
        got = np.array([s.rec_top_x * W + 1, s.rec_top_y * H + 1,
                        (s.rec_bottom_x - s.rec_top_x) * W, (s.rec_bottom_y - s.rec_top_y) * H])
        assert np.abs(boxes - got).max(axis=1).min() < 0.05, got
        assert s.point_x == pytest.approx(s.rec_top_x + (s.rec_bottom_x - s.rec_top_x) / 2,
                                          abs=1e-6)

    # an unusable rectangle: denied, the session goes on
    result, texts = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0.5, 0.5, 0.4, 0.6)
    assert result == mav.MAV_RESULT_DENIED and any("bottom-right" in t for t in texts)
    assert endpoint.cameras[0].session_id == session

    # a point: the same session, re-initialised on a square
    result, _ = station.command(mav.MAV_CMD_CAMERA_TRACK_POINT, (x - 1 + w / 2) / W,
                                (y - 1 + h / 2) / H, 0.02)
    assert result == mav.MAV_RESULT_ACCEPTED
    assert endpoint.cameras[0].session_id == session
    _wait(lambda: any(r.session_id == session and r.status == "reinitialized"
                      for r in list(results)))
    t0 = time.monotonic()
    # statuses after the re-initialisation report the point
    _wait(lambda: any(s.tracking_mode == mav.CAMERA_TRACKING_MODE_POINT for s in statuses(t0)))
    point = statuses(t0)[-1]
    assert point.tracking_mode == mav.CAMERA_TRACKING_MODE_POINT
    assert point.radius == pytest.approx(0.02, abs=0.01)

    # an unknown command: unsupported
    result, _ = station.command(mav.MAV_CMD_DO_SET_MODE, 1)
    assert result == mav.MAV_RESULT_UNSUPPORTED

    # stop: acknowledged, idle, and the service runs no session
    result, _ = station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)
    assert result == mav.MAV_RESULT_ACCEPTED
    t0 = time.monotonic()  # after the stop's ack: every later status says idle
    _wait(lambda: len(station.since(t0, "CAMERA_TRACKING_IMAGE_STATUS")) >= 2)
    after = station.since(t0, "CAMERA_TRACKING_IMAGE_STATUS")
    assert after and all(s.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_IDLE
                         for s in after)
    assert client.status(STREAM).sessions == []
    sub.close()


def test_a_stream_that_stops_leaves_active_until_its_frames_resume(rig: dict[str, Any]) -> None:
    """The station's frames stop: the service's stale notice reaches the camera, whose
    status leaves ACTIVE (ERROR, no box) and says so; frames again: results, and a box."""
    station, endpoint, client = rig["station"], rig["endpoint"], rig["client"]
    results: list = []
    sub = client.results(STREAM, callback=results.append)
    rig["publishing"].set()
    _wait(lambda: endpoint.link_up and endpoint.cameras[0].last_frame is not None)
    assert station.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL,
                           mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS, 100_000)[0] == \
        mav.MAV_RESULT_ACCEPTED
    seq = endpoint.cameras[0].last_frame.seq
    x, y, w, h = rig["gt"][seq % rig["n"]]
    W, H = 1280, 720
    assert station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, (x - 1) / W, (y - 1) / H,
                           (x - 1 + w) / W, (y - 1 + h) / H)[0] == mav.MAV_RESULT_ACCEPTED
    session = endpoint.cameras[0].session_id

    def statuses(since: float) -> list[Any]:
        return [s for s in station.since(since, "CAMERA_TRACKING_IMAGE_STATUS")
                if s.get_srcComponent() == COMP]

    def mine(status: str) -> list[Any]:
        return [r for r in list(results) if r.session_id == session and r.status == status]

    t0 = time.monotonic()
    _wait(lambda: any(s.target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS
                      for s in statuses(t0)), timeout=30)  # tracking, with its box

    rig["publishing"].clear()  # the stream stops
    _wait(lambda: mine("stale"), timeout=30)
    notice = mine("stale")[0]
    answered = [r for r in list(results) if r.session_id == session and r.track_state]
    assert notice.code == "no_frames" and "not current" in (notice.message or "")
    assert notice.frame_seq == max(r.frame_seq for r in answered)  # the last frame's
    assert all(np.isnan(notice.box)) and notice.track_state is None
    assert notice.confidence is None
    _wait(lambda: endpoint.cameras[0].stale)
    t1 = time.monotonic()
    _wait(lambda: len(statuses(t1)) >= 3)
    assert all(_no_box(s) for s in statuses(t1))  # never ACTIVE, no box to follow
    assert endpoint.counts["stale"] == 1
    assert any("tracking stale" in m.text for m in station.since(t0, "STATUSTEXT"))
    # a box drawn now would land on a picture long gone: refused, saying why
    _wait(lambda: not endpoint._video_running(endpoint.cameras[0]))
    result, texts = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0.4, 0.4, 0.6, 0.6)
    assert result == mav.MAV_RESULT_DENIED and any("not delivering" in t for t in texts)
    assert endpoint.cameras[0].session_id == session  # the session waits for its frames

    rig["publishing"].set()  # frames again: results about them, then a box again
    _wait(lambda: [r for r in mine("tracking") if r.frame_seq > notice.frame_seq], timeout=30)
    back = min((r for r in mine("tracking") if r.frame_seq > notice.frame_seq),
               key=lambda r: r.frame_seq)
    assert back.dropped == back.frame_seq - notice.frame_seq - 1  # the pause lost no frame
    t2 = time.monotonic()
    _wait(lambda: any(s.target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS
                      for s in statuses(t2)))
    assert endpoint.counts["stale_ended"] == 1
    assert any("tracking resumed" in m.text for m in station.since(t1, "STATUSTEXT"))
    assert station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)[0] == mav.MAV_RESULT_ACCEPTED
    sub.close()


def test_a_lost_link_and_garbage_do_not_stop_the_camera(rig: dict[str, Any]) -> None:
    station, endpoint = rig["station"], rig["endpoint"]
    rig["publishing"].set()
    _wait(lambda: endpoint.link_up and endpoint.cameras[0].last_frame is not None)
    result, _ = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0.4, 0.4, 0.5, 0.5)
    assert result == mav.MAV_RESULT_ACCEPTED
    # garbage on the MAVLink port: counted, harmless
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for _ in range(5):
            s.sendto(b"\xfd\x09garbage-not-mavlink" * 3, ("127.0.0.1", rig["port"]))
    # the station goes quiet: the link is lost, the session goes on
    station.alive.clear()
    _wait(lambda: endpoint.counts["link_lost"] == 1, timeout=5)
    assert not endpoint.link_up and endpoint.cameras[0].session_id is not None
    # and comes back: found again, commands work
    station.alive.set()
    _wait(lambda: endpoint.link_up, timeout=5)
    result, _ = station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)
    assert result == mav.MAV_RESULT_ACCEPTED
    assert endpoint.counts["link_up"] == 2
    assert endpoint.counts["malformed"] + endpoint.counts["receive_errors"] > 0


def test_hostile_parameters_retransmissions_and_rates(rig: dict[str, Any]) -> None:
    """What a careless or hostile station sends: NaN and infinite whole-number parameters
    are refused and never stop the camera; a retransmitted command (confirmation > 0) gets
    its first acknowledgement again instead of a second execution; interval 0 restores the
    default rate; a broadcast may name the camera by its component id."""
    station, endpoint, client = rig["station"], rig["endpoint"], rig["client"]
    rig["publishing"].set()
    _wait(lambda: endpoint.link_up and endpoint.cameras[0].last_frame is not None)
    nan, inf = float("nan"), float("inf")
    assert station.command(mav.MAV_CMD_REQUEST_MESSAGE, nan)[0] == mav.MAV_RESULT_DENIED
    assert station.command(mav.MAV_CMD_REQUEST_MESSAGE, inf)[0] == mav.MAV_RESULT_DENIED
    assert station.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, nan, 1e5)[0] == \
        mav.MAV_RESULT_DENIED
    assert station.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL,
                           mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS, nan)[0] == \
        mav.MAV_RESULT_DENIED
    # a broadcast with a NaN camera id is for no camera: no ack, and the camera lives on
    station.conn.mav.command_long_send(1, 0, mav.MAV_CMD_CAMERA_STOP_TRACKING, 0, inf,
                                       0, 0, 0, 0, 0, 0)
    station.conn.mav.command_long_send(1, 0, mav.MAV_CMD_CAMERA_TRACK_POINT, 0, 0.5, 0.5,
                                       0.02, nan, 0, 0, 0)
    _wait(lambda: endpoint.counts["bad_camera_id"] == 2)
    assert endpoint.alive and endpoint.counts["internal_errors"] == 0

    # interval 0: back to the default rate (1 Hz in this rig)
    assert station.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL,
                           mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS, 20_000)[0] == \
        mav.MAV_RESULT_ACCEPTED
    assert endpoint.cameras[0].status_interval_s == pytest.approx(0.02)
    assert station.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL,
                           mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS, 0)[0] == \
        mav.MAV_RESULT_ACCEPTED
    assert endpoint.cameras[0].status_interval_s == pytest.approx(1.0)

    # a broadcast naming the camera by its component id
    results: list = []
    sub = client.results(STREAM, callback=results.append)
    rect = (0.4, 0.4, 0.5, 0.5)
    assert station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, *rect, COMP,
                           component=0)[0] == mav.MAV_RESULT_ACCEPTED
    session = endpoint.cameras[0].session_id
    assert session is not None
    # the same rectangle again, as a new command: re-initialised
    assert station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, *rect)[0] == \
        mav.MAV_RESULT_ACCEPTED
    _wait(lambda: sum(r.status == "reinitialized" for r in list(results)) == 1)
    # ...and its retransmission (confirmation 1): the same ack, not a second execution
    assert station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, *rect, confirmation=1)[0] == \
        mav.MAV_RESULT_ACCEPTED
    assert endpoint.counts["retransmissions"] == 1
    assert station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)[0] == mav.MAV_RESULT_ACCEPTED
    # the session's results come in order: a second execution's re-initialisation would be
    # in before its stopped result
    _wait(lambda: any(r.session_id == session and r.status == "stopped"
                      for r in list(results)))
    assert sum(r.status == "reinitialized" for r in list(results)) == 1
    sub.close()


def test_a_preset_or_override_the_service_refuses_is_caught_at_start_up(
        rig: dict[str, Any]) -> None:
    from arcf.adapters.mavlink import check_preset

    client = rig["client"]
    check_preset(client, "arcf-hc", {"state.reacquire": True})
    check_preset(client, "ARCF_HC", {})  # named as the service names it, as a start would be
    for preset, overrides, fragment in (  # the service's own reasons
            ("arcf-xx", {}, "unknown preset 'arcf-xx'"),
            ("arcf-hc", {"gamma": 1000.0}, r"gamma must be a finite number in \[0, 100\]"),
            ("arcf-hc", {"no_such": 1}, r"unknown parameter\(s\) \['no_such'\]"),
            ("arcf-hc", {"state.reacquire": 1}, "state.reacquire must be true or false"),
            ("arcf-hc", {"fhog_sse_table": "/etc/passwd"}, "names a file on the service")):
        with pytest.raises(ValueError, match=fragment):
            check_preset(client, preset, overrides)

