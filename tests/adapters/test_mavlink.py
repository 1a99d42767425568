"""The MAVLink camera endpoint against a real service, driven by a ground station played with
pymavlink over UDP on loopback: capability discovery, rectangle and point tracking on a real
sequence, status at the requested rate with the service's boxes, stop, denials, a lost link."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from adapters.mavlink import CameraConfig, MavlinkCameras, point_box, rectangle_box
from arcf.data import data_root
from arcf.eval import load_dataset
from loadtools.procs import ServiceProcess, free_port
from service.client import TrackingClient

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


class Station:
    """A ground station: heartbeats at 2 Hz (while ``alive``), commands, and every message
    it receives kept by type."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                               source_component=mav.MAV_COMP_ID_MISSIONPLANNER)
        self.alive = threading.Event()
        self.alive.set()
        self.received: list[Any] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._beat, daemon=True),
                         threading.Thread(target=self._listen, daemon=True)]
        for t in self._threads:
            t.start()

    def _beat(self) -> None:
        while not self._stop.wait(0.5):
            if self.alive.is_set():
                self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mav.MAV_STATE_ACTIVE)

    def _listen(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is not None and msg.get_type() != "BAD_DATA":
                with self._lock:
                    self.received.append((time.monotonic(), msg))

    def since(self, t0: float, kind: str) -> list[Any]:
        with self._lock:
            return [m for t, m in self.received if t >= t0 and m.get_type() == kind]

    def command(self, command: int, *params: float, component: int = COMP,
                timeout: float = 10.0, confirmation: int = 0) -> tuple[int, list[str]]:
        """Send a COMMAND_LONG; its COMMAND_ACK's result and the STATUSTEXTs sent with it."""
        t0 = time.monotonic()
        p = [*params, *[0.0] * (7 - len(params))]
        self.conn.mav.command_long_send(1, component, command, confirmation, *p)
        deadline = t0 + timeout
        while time.monotonic() < deadline:
            acks = [a for a in self.since(t0, "COMMAND_ACK") if a.command == command]
            if acks:
                time.sleep(0.05)  # a STATUSTEXT goes just before its ack
                texts = [m.text for m in self.since(t0, "STATUSTEXT")]
                return acks[0].result, texts
            time.sleep(0.01)
        raise AssertionError(f"no COMMAND_ACK for {command} within {timeout} s")

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2)
        self.conn.close()


@pytest.fixture(scope="module")
def sequence() -> Any:
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    return seq


@pytest.fixture
def rig(sequence: Any) -> Iterator[dict[str, Any]]:
    """A service, a station publishing the sequence's JPEG frames at 10 fps (looped, seq
    increasing), the MAVLink endpoint on a loopback UDP port and a MAVLink ground station."""
    service = ServiceProcess(workers=1)
    port = free_port()
    publisher = TrackingClient(connect=[service.endpoint], frame_congestion="block")
    endpoint_client = TrackingClient(connect=[service.endpoint])
    endpoint = MavlinkCameras(endpoint_client, f"udpin:127.0.0.1:{port}",
                              [CameraConfig(STREAM, COMP)], link_timeout_s=1.0,
                              status_interval_s=1.0).start()
    station = Station(port)
    data = [p.read_bytes() for p in sequence.frames]
    publishing = threading.Event()
    stop = threading.Event()
    sent: list[int] = []

    def publish() -> None:
        publishing.wait()
        for seq in range(600):  # bounded: 60 s at 10 fps
            if stop.is_set():
                return
            publisher.publish_frame(STREAM, data=data[seq % len(data)], seq=seq)
            sent.append(seq)
            time.sleep(0.1)

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


def _wait(predicate: Any, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.02)


def test_a_ground_station_tracks_through_the_mavlink_camera(rig: dict[str, Any]) -> None:
    station, endpoint, client = rig["station"], rig["endpoint"], rig["client"]
    _wait(lambda: endpoint.link_up)  # the station's heartbeat was seen

    # no frame yet: denied, saying why
    result, texts = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0.4, 0.4, 0.6, 0.6)
    assert result == mav.MAV_RESULT_DENIED and any("no frames" in t for t in texts)

    results: list = []
    sub = client.results(STREAM, callback=results.append)
    rig["publishing"].set()
    _wait(lambda: endpoint.cameras[0].last_frame is not None)

    # capability discovery: a tracking camera with the stream's resolution
    t0 = time.monotonic()
    result, _ = station.command(mav.MAV_CMD_REQUEST_MESSAGE,
                                mav.MAVLINK_MSG_ID_CAMERA_INFORMATION)
    assert result == mav.MAV_RESULT_ACCEPTED
    _wait(lambda: station.since(t0, "CAMERA_INFORMATION"))
    info = station.since(t0, "CAMERA_INFORMATION")[0]
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
    time.sleep(0.5)
    t0 = time.monotonic()
    time.sleep(3.0)
    status = [s for s in station.since(t0, "CAMERA_TRACKING_IMAGE_STATUS")
              if s.get_srcComponent() == COMP]
    assert 11 <= len(status) <= 19, len(status)  # 15 expected in 3 s
    assert all(s.tracking_mode == mav.CAMERA_TRACKING_MODE_RECTANGLE for s in status)
    assert all(s.tracking_status & mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
               or s.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR for s in status)
    assert all(s.target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS for s in status)
    # each status's rectangle is one of the session's published boxes (float32 on the wire)
    boxes = np.array([r.box for r in list(results) if r.session_id == session
                      and r.track_state is not None])
    for s in status:
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
    _wait(lambda: station.since(t0, "CAMERA_TRACKING_IMAGE_STATUS"))
    time.sleep(0.5)
    point = station.since(t0, "CAMERA_TRACKING_IMAGE_STATUS")[-1]
    assert point.tracking_mode == mav.CAMERA_TRACKING_MODE_POINT
    assert point.radius == pytest.approx(0.02, abs=0.01)

    # an unknown command: unsupported
    result, _ = station.command(mav.MAV_CMD_DO_SET_MODE, 1)
    assert result == mav.MAV_RESULT_UNSUPPORTED

    # stop: acknowledged, idle, and the service runs no session
    result, _ = station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)
    assert result == mav.MAV_RESULT_ACCEPTED
    t0 = time.monotonic()
    time.sleep(0.6)
    after = station.since(t0, "CAMERA_TRACKING_IMAGE_STATUS")
    assert after and all(s.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_IDLE
                         for s in after)
    assert client.status(STREAM).sessions == []
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
    time.sleep(1.0)
    assert sum(r.status == "reinitialized" for r in list(results)) == 1
    assert station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)[0] == mav.MAV_RESULT_ACCEPTED
    sub.close()


def test_a_preset_or_override_the_service_refuses_is_caught_at_start_up(
        rig: dict[str, Any]) -> None:
    from adapters.mavlink import check_preset

    client = rig["client"]
    check_preset(client, "arcf-hc", {"state.reacquire": True})
    for preset, overrides, fragment in (
            ("arcf-xx", {}, "unknown preset"),
            ("arcf-hc", {"gamma": 1000.0}, "within"),
            ("arcf-hc", {"no_such": 1}, "unknown override"),
            ("arcf-hc", {"state.reacquire": 1}, "a bool")):
        with pytest.raises(ValueError, match=fragment):
            check_preset(client, preset, overrides)

