"""Nested parameters through the adapters: ``arcf-mavlink --set state.reacquire=true`` (the
real command, its start-up check against the presets reply, then a station's track command)
and a ROS 2 bridge given ``{"state.reacquire": True}``. Each runs a real session on a real
service over loopback, fed JPEG frames of a scene whose target vanishes and comes back far
away, and the session re-acquires it; a bad dotted name or value is refused with its reason."""

from __future__ import annotations

import logging
import os
import select
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("zenoh")
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from arcf.adapters import ros2_types as rt
from arcf.adapters.ros2 import Ros2Bridge, topic_key
from arcf.client import TrackingClient
from arcf.client.transport import open_session
from arcf.loadtools.procs import ServiceProcess, free_port, terminate
from arcf.loadtools.waiting import wait_until
from arcf.schemas import Result

mav = mavutil.mavlink
pytestmark = pytest.mark.integration

NESTED = ["--set", "state.reacquire=true", "--set", "state.probes=3"]
COMP = 100
ARCF_MAVLINK = Path(sys.executable).parent / "arcf-mavlink"


@pytest.fixture(scope="module")
def service() -> Iterator[ServiceProcess]:
    svc = ServiceProcess(workers=1)
    yield svc
    assert svc.stop() == 0


def _wait(predicate: Any, timeout: float = 30.0, what: str = "condition") -> None:
    wait_until(predicate, timeout=timeout, what=what)


def _publisher(node: Any, key: str) -> Any:
    """A publisher on ``key`` once a subscriber (the bridge's) is known to it: a put before
    the bridge's subscription reached the router would go nowhere. Blocking, so that the
    station's own queue drops nothing."""
    import zenoh

    pub = node.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    _wait(lambda: pub.matching_status.matching, what=f"a subscriber of {key}")
    return pub


def _close(*opened: Any) -> None:
    """Close what a test opened, in order, passing over what it never got to open (None)."""
    for part in opened:
        if part is not None:
            part.close()


# ---------------------------------------------------------------------------------- MAVLink
class Mavlink:
    """``arcf-mavlink`` as an operator starts it (its console script, its own process),
    listening on a loopback UDP port for one camera."""

    def __init__(self, service: ServiceProcess, stream: str, *sets: str) -> None:
        if not ARCF_MAVLINK.is_file():
            pytest.skip("arcf-mavlink is not installed in this environment")
        self.port = free_port()
        self.proc = subprocess.Popen(
            [str(ARCF_MAVLINK), "--mavlink", f"udpin:127.0.0.1:{self.port}", "--camera",
             f"{stream}={COMP}", "--connect", service.endpoint, "--preset", "arcf-hc", *sets],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def wait_started(self, timeout: float = 60.0) -> str:
        """Its start-up line (``arcf-mavlink: 1 camera(s) on ...``), or '' when it exited."""
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        return self.proc.stdout.readline().strip() if ready else ""

    def stop(self) -> int:
        return terminate(self.proc)


class Station:
    """A ground station (pymavlink on loopback UDP): heartbeats, commands and their acks."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                               source_component=mav.MAV_COMP_ID_MISSIONPLANNER)
        self.received: list[tuple[float, Any]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._listen, daemon=True)
        self._thread.start()

    def _listen(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_beat:
                next_beat = time.monotonic() + 0.5
                self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mav.MAV_STATE_ACTIVE)
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is not None and msg.get_type() in ("COMMAND_ACK", "STATUSTEXT"):
                with self._lock:
                    self.received.append((time.monotonic(), msg))

    def command(self, command: int, *params: float, timeout: float = 15.0
                ) -> tuple[int, str]:
        """A COMMAND_LONG to the camera: its COMMAND_ACK's result and the STATUSTEXT chunks
        sent with it, joined."""
        t0 = time.monotonic()
        self.conn.mav.command_long_send(1, COMP, command, 0,
                                        *[*params, *[0.0] * (7 - len(params))])

        def ack() -> Any:
            with self._lock:
                return next((m for t, m in self.received if t >= t0
                             and m.get_type() == "COMMAND_ACK" and m.command == command), None)

        _wait(lambda: ack() is not None, timeout, f"the ack of command {command}")
        with self._lock:  # a STATUSTEXT goes before its ack
            text = "".join(m.text for t, m in self.received
                           if t >= t0 and m.get_type() == "STATUSTEXT")
        return ack().result, text

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.conn.close()


def _track_command(kind: str, box: tuple[int, int, int, int], size: tuple[int, int]
                   ) -> tuple[Any, ...]:
    """The station's command for a 1-based box of a frame of ``size`` (width, height)."""
    x, y, w, h = box
    W, H = size
    if kind == "rectangle":
        return (mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, (x - 1) / W, (y - 1) / H,
                (x - 1 + w) / W, (y - 1 + h) / H)
    return (mav.MAV_CMD_CAMERA_TRACK_POINT, (x - 1 + w / 2) / W, (y - 1 + h / 2) / H,
            w / 2 / W)


@pytest.mark.parametrize("kind", ["rectangle", "point"])
def test_arcf_mavlink_with_a_dotted_set_tracks_and_reacquires(
        service: ServiceProcess, reacquire_scenario: Any, kind: str) -> None:
    """``arcf-mavlink --set state.reacquire=true --set state.probes=3`` starts (the presets
    reply accepts both), a station's track command is ACCEPTED, and the session it started
    finds the target again where it came back."""
    stream = "mav-" + uuid.uuid4().hex[:8]
    adapter = Mavlink(service, stream, *NESTED)
    results: list[Result] = []
    station = publisher = sub = None
    try:
        assert "camera(s)" in adapter.wait_started(), adapter.proc.stderr.read()  # type: ignore[union-attr]
        station = Station(adapter.port)
        publisher = TrackingClient(connect=[service.endpoint], frame_congestion="block")
        sub = publisher.results(stream, callback=results.append)
        first = reacquire_scenario.jpegs[0]
        height, width = reacquire_scenario.image(0).shape[:2]
        command = _track_command(kind, reacquire_scenario.init_box, (width, height))
        # the scene's first frame until the camera has seen one and accepts the command
        seq, deadline = 0, time.monotonic() + 30
        while True:
            publisher.publish_frame(stream, data=first, seq=seq)
            result, text = station.command(*command)
            if result != mav.MAV_RESULT_DENIED or time.monotonic() > deadline:
                break
            assert "no frames yet" in text, text
            seq += 1
        assert result == mav.MAV_RESULT_ACCEPTED, text
        base = seq  # scene frame k goes out as seq base + k

        def answered(k: int) -> bool:
            return any(r.frame_seq == base + k and r.track_state is not None
                       for r in list(results))

        reacquire_scenario.replay(
            lambda k, jpeg: publisher.publish_frame(stream, data=jpeg, seq=base + k),
            answered, start=1)
        assert station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)[0] == mav.MAV_RESULT_ACCEPTED
    finally:
        _close(sub, publisher, station)
        code = adapter.stop()
    assert code == 0
    tracked = [(r.frame_seq - base, r.box, bool(r.reacquired)) for r in results
               if r.track_state is not None]
    assert len({s.session_id for s in results if s.track_state is not None}) == 1
    # every frame from the first after the command (the one it was drawn on too, when the
    # service already had it)
    assert {k for k, _, _ in tracked} >= set(range(1, reacquire_scenario.length))
    assert reacquire_scenario.reacquisitions(tracked), \
        "the session started through MAVLink never re-acquired the target at its new place"


@pytest.mark.parametrize(("setting", "words"), [  # the service's own reasons
    ("state.nope=1", "unknown state parameter(s) ['nope']"),
    ("state.probes=0", "state.probes must be an integer in [1, 16], got 0"),
    ("state.reacquire=maybe", "state.reacquire must be true or false, got 'maybe'"),
    ("foo.bar=1", "unknown parameter 'foo.bar'"),
    # each value within its own range, the pair inconsistent (lost_below above
    # coast_below): the service checks it as it checks a start, so it is caught here too
    ("state.lost_below=0.9", "state thresholds must satisfy 0 <= lost_below <= coast_below"),
])
def test_arcf_mavlink_refuses_a_bad_dotted_set_at_start_up(
        service: ServiceProcess, setting: str, words: str) -> None:
    adapter = Mavlink(service, "mav-bad", "--set", "state.reacquire=true", "--set", setting)
    try:
        assert adapter.wait_started() == ""  # no camera started
        assert adapter.proc.wait(timeout=60) == 2
        assert adapter.proc.stderr is not None
        assert words in adapter.proc.stderr.read()
    finally:
        adapter.stop()


# ------------------------------------------------------------------------------------ ROS 2
IMAGE_TOPIC = "/camera/image/compressed"


def _header(k: int) -> Any:
    return rt.message("std_msgs/msg/Header",
                      stamp=rt.message("builtin_interfaces/msg/Time", sec=1000 + k, nanosec=0),
                      frame_id="cam")


def _track_request(box: tuple[int, int, int, int]) -> bytes:
    """A ``vision_msgs/msg/Detection2D`` asking to track a 1-based box (0-based centre)."""
    x, y, w, h = box
    bbox = rt.message(
        "vision_msgs/msg/BoundingBox2D",
        center=rt.message("vision_msgs/msg/Pose2D",
                          position=rt.message("vision_msgs/msg/Point2D", x=x - 1 + w / 2,
                                              y=y - 1 + h / 2),
                          theta=0.0),
        size_x=float(w), size_y=float(h))
    return rt.serialize(rt.message(rt.DETECTION_2D, header=_header(0), results=[], bbox=bbox,
                                   id=""), rt.DETECTION_2D)


def _image(k: int, jpeg: bytes) -> bytes:
    return rt.serialize(rt.message(rt.COMPRESSED_IMAGE, header=_header(k), format="jpeg",
                                   data=np.frombuffer(jpeg, dtype=np.uint8)),
                        rt.COMPRESSED_IMAGE)


def test_a_ros2_bridge_with_dotted_overrides_reacquires(
        service: ServiceProcess, reacquire_scenario: Any) -> None:
    """``Ros2Bridge(overrides={"state.reacquire": True, "state.probes": 3})``: a track request
    on ``/arcf/<stream>/track`` starts a session that re-acquires the target, fed by
    ``CompressedImage`` JPEGs on the image topic."""
    stream = "ros-" + uuid.uuid4().hex[:8]
    client = TrackingClient(connect=[service.endpoint])
    bridge = Ros2Bridge(TrackingClient(connect=[service.endpoint]), {IMAGE_TOPIC: stream},
                        overrides={"state.reacquire": True, "state.probes": 3})
    node = open_session("client", connect=[service.endpoint])  # the ROS 2 nodes
    results: list[Result] = []
    try:
        sub = client.results(stream, callback=results.append)
        _publisher(node, topic_key(0, f"/arcf/{stream}/track", rt.DETECTION_2D)).put(
            _track_request(reacquire_scenario.init_box))
        _wait(lambda: bridge.counts["starts"] + bridge.counts["refused"] >= 1,
              what="the bridge to start a session")
        assert (bridge.counts["starts"], bridge.counts["refused"]) == (1, 0)
        images = _publisher(node, topic_key(0, IMAGE_TOPIC, rt.COMPRESSED_IMAGE))
        reacquire_scenario.replay(
            lambda k, jpeg: images.put(_image(k, jpeg)),
            lambda k: any(r.frame_seq == k and r.track_state is not None
                          for r in list(results)))
        sub.close()
    finally:
        bridge.close()
        bridge.client.close()
        node.close()
        client.close()
    tracked = [(r.frame_seq, r.box, bool(r.reacquired)) for r in results
               if r.track_state is not None]
    assert sorted(k for k, _, _ in tracked) == list(range(reacquire_scenario.length))
    assert reacquire_scenario.reacquisitions(tracked), \
        "the session started through ROS 2 never re-acquired the target at its new place"


def test_a_ros2_bridge_with_a_bad_dotted_override_logs_the_refusal(
        service: ServiceProcess, reacquire_scenario: Any,
        caplog: pytest.LogCaptureFixture) -> None:
    stream = "ros-" + uuid.uuid4().hex[:8]
    client = TrackingClient(connect=[service.endpoint])
    bridge = Ros2Bridge(TrackingClient(connect=[service.endpoint]), {IMAGE_TOPIC: stream},
                        overrides={"state.reacquire": True, "state.nope": 1})
    node = open_session("client", connect=[service.endpoint])
    try:
        with caplog.at_level(logging.WARNING, logger="arcf.adapters.ros2"):
            _publisher(node, topic_key(0, f"/arcf/{stream}/track", rt.DETECTION_2D)).put(
                _track_request(reacquire_scenario.init_box))
            _wait(lambda: bridge.counts["refused"] == 1, what="the refusal")
        assert bridge.counts["starts"] == 0
        assert any("invalid_parameter" in r.getMessage()
                   and "unknown state parameter(s) ['nope']" in r.getMessage()
                   for r in caplog.records), [r.getMessage() for r in caplog.records]
        assert client.status(stream).sessions == []
    finally:
        bridge.close()
        bridge.client.close()
        node.close()
        client.close()


# ---------------------------------------------------------------------------------- arcf-ros2
ARCF_ROS2 = Path(sys.executable).parent / "arcf-ros2"


@pytest.mark.parametrize(("sets", "words"), [
    (("--set", "state.reacquire=false", "--set", "state.probes=3"), None),
    (("--set", "state.nope=1"), "unknown state parameter(s) ['nope']"),
    (("--set", "state.probes=0"), "state.probes must be an integer in [1, 16], got 0"),
])
def test_arcf_ros2_takes_dotted_sets_and_refuses_bad_ones_at_start_up(
        service: ServiceProcess, sets: tuple[str, ...], words: str | None) -> None:
    """``arcf-ros2 --set state.reacquire=false``, as an operator starts it: a good nested
    override starts the node, a bad one ends the command with code 2 and the reason (not a
    refusal logged at the first track request)."""
    if not ARCF_ROS2.is_file():
        pytest.skip("arcf-ros2 is not installed in this environment")
    proc = subprocess.Popen(
        [str(ARCF_ROS2), "--image", "/cam/image/compressed=ros-cmd", "--connect",
         service.endpoint, "--preset", "arcf-h", *sets],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stderr is not None
        ready, _, _ = select.select([proc.stdout], [], [], 60.0)
        line = proc.stdout.readline().strip() if ready else ""
        if words is None:
            assert line.startswith("arcf-ros2: node /arcf"), line
        else:
            assert line == ""
            assert proc.wait(timeout=60) == 2
            assert words in proc.stderr.read()
    finally:
        terminate(proc)
