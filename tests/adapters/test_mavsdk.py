"""MAVSDK-Python as the ground station against the MAVLink camera: a client nobody here wrote.

MAVSDK (``mavsdk`` on PyPI, its C++ core in the wheel) discovers the camera, reads its
information and video stream, and drives tracking with the calls its Camera plugin offers
(``track_rectangle``, ``track_point``, ``track_stop``). The plugin has no call for the
tracking status; MAVSDK's own ``MavlinkDirect`` plugin reads ``CAMERA_TRACKING_IMAGE_STATUS``
(and the reasons in ``STATUSTEXT``), as docs/mavlink.md says."""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

mavsdk = pytest.importorskip("mavsdk")

from mavsdk import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.plugins.camera import Camera, CameraError, CameraResult  # noqa: E402
from mavsdk.plugins.mavlink_direct import MavlinkDirect  # noqa: E402

from arcf.adapters.mavlink import CameraConfig, MavlinkCameras, VideoStream  # noqa: E402
from arcf.client import TrackingClient  # noqa: E402
from arcf.data import data_root  # noqa: E402
from arcf.loadtools.procs import ServiceProcess, free_port  # noqa: E402
from arcf.loadtools.waiting import wait_until  # noqa: E402

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

STREAM, COMP, W, H = "cam1", 100, 1280, 720
URI = "rtsp://127.0.0.1:8554/cam1"
# CAMERA_TRACKING_STATUS_FLAGS and CAMERA_TRACKING_MODE, as the MAVLink common set numbers them
IDLE, ACTIVE, ERROR = 0, 1, 2
MODE_POINT, MODE_RECTANGLE = 1, 2
TARGET_IN_STATUS = 4


class Station:
    """MAVSDK as a ground station: one system, its Camera plugin, and every
    ``CAMERA_TRACKING_IMAGE_STATUS`` and ``STATUSTEXT`` as MavlinkDirect decodes them."""

    def __init__(self, port: int) -> None:
        self.mavsdk = Mavsdk(Configuration.create_with_component_type(
            ComponentType.GROUND_STATION))
        self.mavsdk.add_any_connection(f"udpout://127.0.0.1:{port}")
        wait_until(lambda: any(s.has_camera() for s in self.mavsdk.get_systems()),
                   timeout=30, what="MAVSDK discovering a camera")
        (self.system,) = self.mavsdk.get_systems()
        self.camera = Camera(self.system)
        self.direct = MavlinkDirect(self.system)
        self._lock = threading.Lock()
        self.statuses: list[tuple[float, dict[str, Any]]] = []
        self.texts: list[tuple[float, str]] = []
        self.direct.subscribe_message("CAMERA_TRACKING_IMAGE_STATUS", self._status)
        self.direct.subscribe_message("STATUSTEXT", self._text)

    def _status(self, message: Any, _user_data: Any = None) -> None:
        with self._lock:
            self.statuses.append((time.monotonic(), json.loads(message.fields_json)))

    def _text(self, message: Any, _user_data: Any = None) -> None:
        with self._lock:
            self.texts.append((time.monotonic(), json.loads(message.fields_json)["text"]))

    def statuses_since(self, t0: float) -> list[dict[str, Any]]:
        with self._lock:
            return [s for t, s in self.statuses if t >= t0]

    def texts_since(self, t0: float) -> list[str]:
        with self._lock:
            return [x for t, x in self.texts if t >= t0]

    def close(self) -> None:
        self.camera.destroy()
        self.direct.destroy()
        self.mavsdk.destroy()


@pytest.fixture
def rig(wakeboard7: Any) -> Iterator[dict[str, Any]]:
    """A service, the sequence's JPEG frames published at 10 fps (looped, bounded), the
    MAVLink camera advertising an RTSP stream, and MAVSDK linked to it once frames flow."""
    service = ServiceProcess(workers=1)
    port = free_port()
    publisher = TrackingClient(connect=[service.endpoint], frame_congestion="block")
    endpoint_client = TrackingClient(connect=[service.endpoint])
    endpoint = MavlinkCameras(endpoint_client, f"udpin:127.0.0.1:{port}",
                              [CameraConfig(STREAM, COMP, VideoStream.parse(URI))],
                              status_interval_s=0.2).start()
    data = [p.read_bytes() for p in wakeboard7.frames]
    stop = threading.Event()
    results: list[Any] = []
    watch = publisher.results(STREAM, callback=results.append)

    def publish() -> None:
        for seq in range(1200):  # bounded: 2 minutes at 10 fps
            if stop.wait(0.1):  # the stimulus: a 10 fps camera
                return
            publisher.publish_frame(STREAM, data=data[seq % len(data)], seq=seq)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    station = None
    try:
        wait_until(lambda: endpoint.cameras[0].last_frame is not None, timeout=30,
                   what="the camera's first frame")
        station = Station(port)
        yield {"station": station, "endpoint": endpoint, "results": results,
               "gt": np.asarray(wakeboard7.groundtruth), "n": len(data)}
    finally:
        stop.set()
        thread.join(timeout=5)
        if station is not None:
            station.close()
        watch.close()
        endpoint.close()
        endpoint_client.close()
        publisher.close()
        assert service.stop() == 0


def test_mavsdk_discovers_the_camera_and_its_video_stream(rig: dict[str, Any]) -> None:
    station: Station = rig["station"]
    wait_until(lambda: station.camera.camera_list().cameras, timeout=30,
               what="MAVSDK's camera list")
    (info,) = station.camera.camera_list().cameras
    assert info.component_id == COMP
    assert (info.vendor_name, info.model_name) == ("arcf", f"ARCF tracker {STREAM}")
    assert (info.horizontal_resolution_px, info.vertical_resolution_px) == (W, H)
    # the URI the pilot's video player opens: MAVSDK asks with stream id NaN ("all")
    wait_until(lambda: station.camera.get_video_stream_info(COMP).settings.uri == URI,
               timeout=30, what="the video stream's URI in MAVSDK")
    video = station.camera.get_video_stream_info(COMP)
    assert video.stream_id == 1
    assert (video.settings.horizontal_resolution_pix,
            video.settings.vertical_resolution_pix) == (W, H)
    assert video.status == video.VideoStreamStatus.IN_PROGRESS  # frames are flowing


def _rectangle(status: dict[str, Any]) -> np.ndarray:
    """A status's rectangle as a box in pixels (x, y, w, h; 1-based, as the service's)."""
    x0, y0 = status["rec_top_x"] * W, status["rec_top_y"] * H
    return np.array([x0 + 1, y0 + 1, status["rec_bottom_x"] * W - x0,
                     status["rec_bottom_y"] * H - y0])


def test_mavsdk_tracks_points_rectangles_and_stops(rig: dict[str, Any]) -> None:
    station: Station = rig["station"]
    endpoint, results = rig["endpoint"], rig["results"]
    camera = station.camera

    # the target's ground-truth rectangle on the frame the camera shows now
    seq = endpoint.cameras[0].last_frame.seq
    x, y, w, h = rig["gt"][seq % rig["n"]]
    assert camera.track_rectangle(COMP, (x - 1) / W, (y - 1) / H,
                                  (x - 1 + w) / W, (y - 1 + h) / H) == CameraResult.SUCCESS
    session = endpoint.cameras[0].session_id
    assert session is not None

    def tracked() -> list[Any]:
        return [r for r in list(results) if r.session_id == session
                and r.track_state is not None]

    t0 = time.monotonic()
    wait_until(lambda: [s for s in station.statuses_since(t0)
                        if s["target_data"] == TARGET_IN_STATUS], timeout=30,
               what="a status with the target's rectangle, through MAVSDK")
    boxed = [s for s in station.statuses_since(t0) if s["target_data"] == TARGET_IN_STATUS]
    assert all(s["tracking_mode"] == MODE_RECTANGLE for s in boxed)
    assert all(s["tracking_status"] & ACTIVE for s in boxed)
    boxes = np.array([r.box for r in tracked()])
    for s in boxed:  # each rectangle is one of the session's published boxes
        assert np.abs(boxes - _rectangle(s)).max(axis=1).min() < 0.05, s

    # a rectangle the camera cannot use: MAVSDK reports the denial, the STATUSTEXT says why
    t0 = time.monotonic()
    with pytest.raises(CameraError) as denied:
        camera.track_rectangle(COMP, 0.5, 0.5, 0.4, 0.6)
    assert denied.value.result == CameraResult.DENIED
    wait_until(lambda: any("bottom-right" in t for t in station.texts_since(t0)),
               timeout=10, what="the denial's reason")
    assert endpoint.cameras[0].session_id == session  # the track goes on

    # a point: the same session, re-initialised on a square around it
    assert camera.track_point(COMP, (x - 1 + w / 2) / W, (y - 1 + h / 2) / H,
                              0.02) == CameraResult.SUCCESS
    assert endpoint.cameras[0].session_id == session
    wait_until(lambda: any(r.session_id == session and r.status == "reinitialized"
                           for r in list(results)), timeout=30, what="a re-initialised track")
    t0 = time.monotonic()
    wait_until(lambda: any(s["tracking_mode"] == MODE_POINT
                           and s["target_data"] == TARGET_IN_STATUS
                           for s in station.statuses_since(t0)),
               timeout=30, what="a point-mode status")

    # stop: idle, no target, the coordinates NaN (null in MAVSDK's JSON)
    assert camera.track_stop(COMP) == CameraResult.SUCCESS
    assert endpoint.cameras[0].session_id is None
    t0 = time.monotonic()
    wait_until(lambda: station.statuses_since(t0), timeout=10, what="a status after the stop")
    idle = station.statuses_since(t0)[-1]
    assert (idle["tracking_status"], idle["tracking_mode"], idle["target_data"]) == (IDLE, 0, 0)
    assert all(idle[k] is None or math.isnan(idle[k]) for k in ("point_x", "rec_top_x"))
