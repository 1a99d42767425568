"""Keeping the target centred: the follow controller's law (angles, signs, dead band, limits,
letting go), its MAVLink Gimbal Protocol v2 messages on a real pymavlink link, and the closed
loop in simulated time: a virtual gimbal camera looking at a shared sequence's real pictures,
the tracker on its views, the controller steering it, at 10 and 30 Hz."""

from __future__ import annotations

import math
import os
import time
from typing import Any

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from arcf.adapters.gimbal import (
    Command,
    FollowController,
    FollowSettings,
    GimbalFollower,
    Observation,
    angular_offset,
)
from arcf.loadtools.procs import free_port
from arcf.loadtools.waiting import wait_until
from arcf.schemas import Result

mav = mavutil.mavlink
SIZE = (1280, 720)


def seen(cx: float, cy: float, ok: bool = True, size: tuple[int, int] = SIZE) -> Observation:
    """A 40 x 30 box centred at 0-based (cx, cy)."""
    return Observation((cx - 20 + 1, cy - 15 + 1, 40.0, 30.0), size, ok)


def test_angles_and_signs_are_mavlinks() -> None:
    # the centre: no angle; right and down positive, by the pinhole model
    assert angular_offset((621.0, 346.0, 40.0, 30.0), SIZE, 60.0) == pytest.approx((0.0, 0.0))
    right, down = angular_offset((1241.0, 706.0, 40.0, 30.0), SIZE, 60.0)
    assert right == pytest.approx(math.degrees(math.atan(620 / (640 / math.tan(math.pi / 6)))))
    assert down > 0 and right > down
    c = FollowController(FollowSettings(hfov_deg=60.0, gain=2.0, max_accel_dps2=1e6,
                                        max_shift=1e3))
    cmd = c.update(seen(1000.0, 200.0), 0.0)  # right of and above the centre
    assert cmd is not None and cmd.yaw_dps > 0 and cmd.pitch_dps > 0  # yaw right, pitch up
    want_yaw, want_up = angular_offset((981.0, 186.0, 40.0, 30.0), SIZE, 60.0)
    assert cmd.yaw_dps == pytest.approx(2.0 * want_yaw)
    assert cmd.pitch_dps == pytest.approx(-2.0 * want_up)


def test_dead_band_rate_and_acceleration_limits() -> None:
    s = FollowSettings(hfov_deg=60.0, gain=2.0, max_rate_dps=30.0, max_accel_dps2=100.0,
                       deadband=0.02, max_shift=1e3)
    c = FollowController(s)
    first = c.update(seen(640.0 + 0.01 * 1280, 360.0), 0.0)  # within the dead band
    assert first == Command(0.0, 0.0)
    # far off: the rate climbs by at most 100 deg/s^2 and stops at 30 deg/s
    rates = []
    for k in range(1, 30):
        cmd = c.update(seen(1270.0, 360.0), 0.05 * k)
        assert cmd is not None
        rates.append(cmd.yaw_dps)
    steps = np.diff([0.0, *rates])
    assert np.all(steps <= 100.0 * 0.05 + 1e-9) and max(rates) == pytest.approx(30.0)


def test_a_small_target_caps_the_rate() -> None:
    """The camera may shift the target by at most ``max_shift`` box sizes between two
    results: a 14 px box seen 10 times a second allows about 4 deg/s, far below the 60 the
    angle alone would ask for."""
    s = FollowSettings(hfov_deg=60.0, max_accel_dps2=1e6, max_shift=0.5)
    c = FollowController(s)
    small = Observation((1201.0, 300.0, 14.0, 11.0), SIZE, True)
    rates = [c.update(small, 0.1 * k) for k in range(5)]
    focal = 640 / math.tan(math.radians(30.0))
    cap = 0.5 * math.degrees(math.atan2(14.0, focal)) / 0.1
    assert all(r is not None and 0 < r.yaw_dps <= cap + 1e-9 for r in rates)
    assert rates[-1] is not None and rates[-1].yaw_dps == pytest.approx(cap)


@pytest.mark.parametrize("why", ["coasting", "lost", "stale", "error", "stopped", "silent"])
def test_the_gimbal_is_let_go_unless_tracking(why: str) -> None:
    """One zero-rate command when the track stops being followable, then nothing, until a
    tracking result comes again."""
    c = FollowController(FollowSettings(timeout_s=1.0))
    assert c.update(seen(1000.0, 360.0), 0.0) is not None and c.engaged
    nan = float("nan")
    bad = {"coasting": seen(1000.0, 360.0, ok=False), "lost": seen(1000.0, 360.0, ok=False),
           "stale": Observation((nan, nan, nan, nan), SIZE, False),
           "error": Observation((nan, nan, nan, nan), SIZE, False),
           "stopped": Observation((nan, nan, nan, nan), SIZE, False)}
    if why == "silent":
        assert c.update(None, 0.5) is None  # a tick within the timeout: nothing new
        out = [c.update(None, 1.5), c.update(None, 1.6), c.update(None, 2.0)]
    else:
        out = [c.update(bad[why], 0.1 * k) for k in range(1, 4)]
    assert out == [Command(0.0, 0.0), None, None] and not c.engaged
    again = c.update(seen(1000.0, 360.0), 3.0)
    assert again is not None and again.yaw_dps > 0 and c.engaged


def _result(status: str, state: str | None, box: list[float]) -> Result:
    return Result(session_id="s", stream_id="cam", frame_seq=1, capture_ts_ns=1, box=box,
                  peak=0.5, psr=9.0, aberrance=0.01, aberrance_release=0.01, scale=1.0,
                  track_state=state, confidence=0.9 if state else None, status=status,
                  dropped=0, received_ts_ns=1, decode_s=0.0, track_s=0.0, published_ts_ns=1)


def test_service_results_as_observations() -> None:
    box = [981.0, 186.0, 40.0, 30.0]
    assert Observation.of(_result("tracking", "tracking", box), SIZE).usable
    assert Observation.of(_result("initialized", None, box), SIZE).usable  # the operator's
    for status, state in (("tracking", "coasting"), ("tracking", "lost"), ("error", None),
                          ("tracking", None)):
        assert not Observation.of(_result(status, state, box), SIZE).usable, (status, state)


def test_gimbal_protocol_v2_on_a_real_link() -> None:
    """Control asked for once, then GIMBAL_MANAGER_SET_PITCHYAW: NaN angles, rates in rad/s
    with MAVLink's signs, at most max_command_hz a second (a fake clock), a stop once."""
    port = free_port()
    autopilot = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1,
                                           source_component=1)
    camera = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1,
                                        source_component=100)
    got: list[Any] = []
    try:
        follower = GimbalFollower(camera.mav.send, (1, 100), (1, 1), gimbal_device_id=0,
                                  settings=FollowSettings(max_accel_dps2=1e6, max_shift=1e3),
                                  max_command_hz=10.0)
        follower.take_control()
        box = [1001.0, 186.0, 40.0, 30.0]
        for k in range(10):  # 10 results in 0.45 s of the fake clock: 5 commands at 10 Hz
            follower.on_result(_result("tracking", "tracking", box), SIZE, 100.0 + 0.05 * k)
        follower.on_result(_result("tracking", "lost", box), SIZE, 100.5)  # let go: at once
        follower.on_result(_result("tracking", "lost", box), SIZE, 100.55)  # nothing more

        def receive() -> bool:
            msg = autopilot.recv_match(blocking=True, timeout=0.1)
            if msg is not None and msg.get_type() in ("COMMAND_LONG",
                                                      "GIMBAL_MANAGER_SET_PITCHYAW"):
                got.append(msg)
            return len(got) >= 7

        wait_until(receive, timeout=30, what="the follower's messages")
        # a sentinel on the same socket: whatever the follower sent arrives before it
        camera.mav.heartbeat_send(mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)

        def sentinel() -> bool:
            msg = autopilot.recv_match(blocking=True, timeout=0.1)
            if msg is not None and msg.get_type() == "GIMBAL_MANAGER_SET_PITCHYAW":
                got.append(msg)
            return msg is not None and msg.get_type() == "HEARTBEAT"

        wait_until(sentinel, timeout=30, what="the sentinel after the follower's messages")
    finally:
        autopilot.close()
        camera.close()
    configure, *commands = got
    assert configure.get_type() == "COMMAND_LONG"
    assert configure.command == mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
    assert (configure.param1, configure.param2, configure.target_component) == (1, 100, 1)
    assert len(commands) == 6 and follower.counts["held"] == 5
    for m in commands[:5]:
        assert math.isnan(m.pitch) and math.isnan(m.yaw)
        assert m.yaw_rate > 0 and m.pitch_rate > 0  # right and up: the target's way
        assert m.flags == mav.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME
    want = math.radians(2.0 * angular_offset(tuple(box), SIZE, 60.0)[0])  # type: ignore[arg-type]
    assert commands[0].yaw_rate == pytest.approx(want, rel=1e-5)
    assert commands[-1].yaw_rate == 0.0 and commands[-1].pitch_rate == 0.0  # let go


# ---------------------------------------------------------------------------- closed loop
def _sequence(name: str) -> Any:
    from arcf.eval import load_dataset

    try:
        (seq,) = load_dataset("uav123_10fps", sequences=[name])
    except (FileNotFoundError, KeyError):
        pytest.skip("needs ../shared/data")
    return seq


@pytest.fixture(scope="module")
def boat1() -> Any:
    return _sequence("boat1")


@pytest.mark.parametrize(("name", "rate_hz"), [("boat1", 10), ("boat1", 30),
                                               ("truck4_1", 10), ("truck4_1", 30)])
def test_the_closed_loop_centres_the_target_without_oscillating(name: str,
                                                                rate_hz: int) -> None:
    """The gimbal starts with the target (a boat; a 14 x 11 px truck) a quarter of the view
    right of the centre and a fifth above it; within 3 s its true centre is within 10 % of
    the view's centre and stays there (the target moves on meanwhile), and while it settles
    the box the controller sees does not swing past the centre by more than 5 % of the view
    (no oscillation)."""
    from arcf.loadtools.gimbalsim import run_follow

    run = run_follow(_sequence(name), rate_hz=rate_hz, seconds=8, start=(0.25, -0.2))
    offsets, t = run.offsets(), np.array(run.t)
    assert run.state.count("tracking") == len(run.state) - 1  # the tracker kept the target
    assert np.abs(offsets[t >= 3.0]).max() < 0.10, np.abs(offsets[t >= 3.0]).max(axis=0)
    # the controller's response to what it sees (the tracker's box, whose own error the
    # true offset includes): no swing past the centre while it settles
    settling = np.array(run.seen)[t < 3.0]
    assert (-settling[:, 0]).max() < 0.05 and settling[:, 1].max() < 0.05
    yaw = np.array([c.yaw_dps for c in run.command if c is not None])
    assert len(yaw) == len(run.command) and yaw[0] > 0  # commanded all along, the right way


def test_the_gimbal_is_let_go_when_the_target_is_lost(boat1) -> None:
    """The boat hidden from 4 s on (a grey patch over it in the world): once the track state
    leaves ``tracking``, one zero-rate command, then none, and the gimbal stops. ARCF-H with
    its search on, so that nothing is learnt while the boat is hidden (as shipped it learns
    every frame, and may learn the patch as its target)."""
    from arcf.loadtools.gimbalsim import run_follow

    gt = np.asarray(boat1.groundtruth, dtype=float)

    def hide(i: int, picture: np.ndarray) -> np.ndarray:
        if i < 40:
            return picture
        x, y, w, h = gt[i]
        out = picture.copy()
        out[int(max(0, y - 1 - h / 2)):int(y - 1 + 1.5 * h),
            int(max(0, x - 1 - w / 2)):int(x - 1 + 1.5 * w)] = 128
        return out

    run = run_follow(boat1, rate_hz=10, seconds=8, world_edit=hide,
                     overrides={"state.reacquire": True})
    first = next(k for k, s in enumerate(run.state) if k > 0 and s != "tracking")
    assert run.t[first] >= 4.0  # flagged after the boat was hidden, not before
    assert all(s != "tracking" for s in run.state[first:])  # hidden to the end
    assert run.command[first] == Command(0.0, 0.0)
    assert all(c is None for c in run.command[first + 1:])
    still = np.array(run.gimbal[first + 3:])  # the motors' lag (50 ms) later
    assert np.ptp(still, axis=0).max() < 1e-3


def test_a_mavlink_camera_with_follow_steers_its_gimbal(offline_client: Any) -> None:
    """``--follow``: a station's rectangle starts the session; the camera takes control of
    the gimbal manager, each tracking result becomes a rate command on the link, a lost
    target one stop, and nothing after it."""
    from types import SimpleNamespace

    from arcf.adapters.gimbal import GimbalTarget
    from arcf.adapters.mavlink import CameraConfig, MavlinkCameras
    from arcf.loadtools.groundstation import GroundStation

    port = free_port()
    endpoint = MavlinkCameras(offline_client, f"udpin:127.0.0.1:{port}",
                              [CameraConfig("cam", 100, follow=GimbalTarget(1, 1))],
                              status_interval_s=0.0).start()
    station = GroundStation(port, 100)
    try:
        wait_until(lambda: endpoint.link_up, timeout=30, what="the station heard")
        (cam,) = endpoint.cameras
        cam.last_frame = SimpleNamespace(width=1280, height=720, seq=7, source="frame",
                                         encoding="jpeg", payload=b"", is_video=False)
        cam.frame_at = math.inf  # a camera that keeps delivering, however slow this machine
        t0 = time.monotonic()
        result, texts = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0.7, 0.2, 0.75,
                                        0.25)
        assert result == mav.MAV_RESULT_ACCEPTED, texts
        wait_until(lambda: [m for m in station.since(t0, "COMMAND_LONG")
                            if m.command == mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE],
                   timeout=30, what="control asked for")
        on_result = offline_client.callbacks["results"]
        box = [897.0, 145.0, 64.0, 36.0]  # right of and above the centre
        on_result(_result("tracking", "tracking", box).model_copy(
            update={"session_id": "s1", "stream_id": "cam"}))

        def commands() -> list[Any]:
            return station.since(t0, "GIMBAL_MANAGER_SET_PITCHYAW")

        wait_until(lambda: commands(), timeout=30, what="a rate command")
        (first,) = commands()
        assert first.target_system == 1 and first.target_component == 1
        assert first.yaw_rate > 0 and first.pitch_rate > 0 and math.isnan(first.yaw)
        for _ in range(2):  # lost: one stop, then nothing
            on_result(_result("tracking", "lost", box).model_copy(
                update={"session_id": "s1", "stream_id": "cam"}))
        wait_until(lambda: len(commands()) == 2, timeout=30, what="the stop")
        # the camera's next heartbeat goes out after anything the follower sent: once it is
        # in, a third command would be too (none may be)
        t_stop = time.monotonic()
        wait_until(lambda: [h for h in station.since(t_stop, "HEARTBEAT")
                            if h.get_srcComponent() == 100], timeout=30,
                   what="a heartbeat after the stop")
        stop = commands()[-1]
        assert len(commands()) == 2 and stop.yaw_rate == 0.0 and stop.pitch_rate == 0.0
        assert cam.follower is not None and cam.follower.counts["stops"] == 1
    finally:
        station.close()
        endpoint.close()
