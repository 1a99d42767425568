"""Keep the target centred: a session's boxes turned into gimbal rate commands.

:class:`FollowController` is the loop's law. The box's offset from the image centre is an
angle (the camera's field of view and a pinhole model), and the command is a rate: the angle
times ``gain`` (1/s) plus the accumulated angle times ``integral`` (1/s^2), which lets the
gimbal keep pace with a moving target (a proportional loop alone lags it by its angular rate
over the gain). The rate is cut to ``max_rate_dps`` and changed by at most ``max_accel_dps2``
per second (a gimbal is not jerked); within ``deadband`` of the centre the error itself adds
nothing. It commands only while the track state says ``tracking``: when the track is
coasting (the box is a prediction), lost, stale (no frames), in error or silent for
``timeout_s``, it asks once for zero rates (a gimbal keeps its last rate otherwise) and then
lets go: no command at all, so the pilot or another controller has the gimbal. It starts
again, from rest, at the next ``tracking`` result.

:class:`GimbalFollower` sends those commands with MAVLink's Gimbal Protocol v2 to a gimbal
manager (the autopilot, ArduPilot's and PX4's, or a gimbal that is its own manager): it takes
control once with ``MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE`` (this component as primary
control), then sends ``GIMBAL_MANAGER_SET_PITCHYAW`` with NaN angles and the two rates (rad/s,
yaw in the vehicle frame), at most ``max_command_hz`` times a second.

Sign conventions (MAVLink's): pitch positive up, yaw positive clockwise seen from above, so
a target right of the centre asks for a positive yaw rate and one below it a negative pitch
rate.
"""

from __future__ import annotations

import math
import os
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from arcf.schemas import Result, ResultStatus, TrackState

mav = mavutil.mavlink


@dataclass(frozen=True)
class FollowSettings:
    """The loop's parameters (angles in degrees)."""

    #: the camera's horizontal field of view (the vertical one follows from the aspect)
    hfov_deg: float = 60.0
    #: rate per angle of error, 1/s
    gain: float = 2.0
    #: rate per accumulated angle of error (angle x seconds), 1/s^2: what lets the gimbal
    #: keep pace with a moving target (a proportional loop alone lags it by its angular rate
    #: over ``gain``). ``gain**2 / 5`` damps the loop a little more than critically
    #: (damping ratio 1.1): it settles without oscillating
    integral: float = 0.8
    #: the fastest rate commanded, deg/s
    max_rate_dps: float = 60.0
    #: how fast the commanded rate may change, deg/s^2
    max_accel_dps2: float = 240.0
    #: no motion while the box's centre is within this share of the frame from its centre
    deadband: float = 0.01
    #: the most the camera's own motion may shift the target in the picture from one result
    #: to the next, in box sizes: a correlation filter searches a window a few box sizes
    #: wide, so a small target at a low frame rate caps the rate more than ``max_rate_dps``
    max_shift: float = 0.5
    #: a session silent this long is let go, s
    timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not 1.0 <= self.hfov_deg < 180.0:
            raise ValueError(f"hfov_deg must be within [1, 180), got {self.hfov_deg}")
        for name in ("gain", "max_rate_dps", "max_accel_dps2", "timeout_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        if not self.integral >= 0:
            raise ValueError("integral must be >= 0")
        if not self.max_shift > 0:
            raise ValueError("max_shift must be > 0")
        if not 0.0 <= self.deadband < 0.5:
            raise ValueError(f"deadband must be within [0, 0.5), got {self.deadband}")


@dataclass(frozen=True)
class Command:
    """Rates to command, deg/s (``None`` from the controller: command nothing)."""

    yaw_dps: float
    pitch_dps: float


def angular_offset(box: tuple[float, float, float, float], size: tuple[int, int],
                   hfov_deg: float) -> tuple[float, float]:
    """The box centre's angles from the optical axis, degrees: (right, down) positive.
    ``box`` is 1-based (x, y, w, h) in pixels of a ``size`` = (width, height) picture."""
    x, y, w, h = box
    width, height = size
    focal = (width / 2) / math.tan(math.radians(hfov_deg) / 2)  # pixels
    dx = (x - 1 + w / 2) - width / 2
    dy = (y - 1 + h / 2) - height / 2
    return math.degrees(math.atan2(dx, focal)), math.degrees(math.atan2(dy, focal))


@dataclass(frozen=True)
class Observation:
    """What the controller needs of one result: the box (1-based x, y, w, h in pixels of a
    ``size`` picture) and whether it may be followed (a measurement with the track state
    ``tracking``; an initialisation's box, the operator's, counts as one)."""

    box: tuple[float, float, float, float]
    size: tuple[int, int]
    followable: bool

    @classmethod
    def of(cls, result: Result, size: tuple[int, int]) -> Observation:
        """A service result's (``size``: its stream's picture size)."""
        measured = result.status in (ResultStatus.TRACKING, ResultStatus.INITIALIZED,
                                     ResultStatus.REINITIALIZED, ResultStatus.RESUMED)
        state_ok = result.track_state is TrackState.TRACKING or (
            result.track_state is None and result.status is not ResultStatus.TRACKING)
        x, y, w, h = result.box
        return cls((x, y, w, h), size, measured and state_ok)

    @property
    def usable(self) -> bool:
        return (self.followable and all(math.isfinite(v) for v in self.box)
                and self.box[2] > 0 and self.box[3] > 0 and min(self.size) > 0)


class FollowController:
    """Results in, rate commands out (see the module docstring)."""

    def __init__(self, settings: FollowSettings | None = None) -> None:
        self.settings = settings or FollowSettings()
        self._last: Command | None = None  # the last command sent (None: let go)
        self._last_t: float | None = None
        #: the accumulated angular errors (yaw, down), degrees x seconds, while engaged
        self._sum = (0.0, 0.0)
        self._heard_t: float | None = None
        self.counts: Counter[str] = Counter()

    @property
    def engaged(self) -> bool:
        """Commanding the gimbal (not let go)."""
        return self._last is not None

    def update(self, seen: Observation | None, now: float) -> Command | None:
        """The command for a new result (or, with ``seen`` None, a tick without one): a
        rate, zero rates once when letting go, or None (nothing to send). ``now``: seconds
        on any monotonic clock."""
        s = self.settings
        if seen is not None:
            self._heard_t = now
        silent = self._heard_t is None or now - self._heard_t > s.timeout_s
        if seen is None and not silent:
            return None  # a tick between results: nothing new
        if silent or seen is None or not seen.usable:
            return self._let_go()
        yaw_err, down_err = angular_offset(seen.box, seen.size, s.hfov_deg)
        width, height = seen.size
        vfov = 2 * math.degrees(math.atan(math.tan(math.radians(s.hfov_deg) / 2)
                                          * height / width))
        band_x, band_y = s.deadband * s.hfov_deg, s.deadband * vfov
        # from rest (just engaged), the first step is a tenth of a second's acceleration
        engaged = self._last is not None and self._last_t is not None
        dt = max(0.0, now - self._last_t) if engaged and self._last_t is not None else 0.1
        if not engaged:
            self._sum = (0.0, 0.0)
        # the camera may move the target by max_shift box sizes between two results (the
        # last interval between them; from rest, a tenth of a second)
        focal = (width / 2) / math.tan(math.radians(s.hfov_deg) / 2)
        box_w = math.degrees(math.atan2(seen.box[2], focal))
        box_h = math.degrees(math.atan2(seen.box[3], focal))
        cap_x = min(s.max_rate_dps, s.max_shift * box_w / max(dt, 1e-3))
        cap_y = min(s.max_rate_dps, s.max_shift * box_h / max(dt, 1e-3))
        want_yaw, sum_yaw = self._axis(yaw_err, band_x, self._sum[0], dt if engaged else 0.0,
                                       cap_x)
        want_down, sum_down = self._axis(down_err, band_y, self._sum[1],
                                         dt if engaged else 0.0, cap_y)
        self._sum = (sum_yaw, sum_down)
        want_pitch = -want_down
        prev = self._last or Command(0.0, 0.0)
        step = s.max_accel_dps2 * dt
        cmd = Command(prev.yaw_dps + max(-step, min(step, want_yaw - prev.yaw_dps)),
                      prev.pitch_dps + max(-step, min(step, want_pitch - prev.pitch_dps)))
        self._last, self._last_t = cmd, now
        self.counts["commands"] += 1
        return cmd

    def _axis(self, err: float, band: float, total: float, dt: float,
              cap: float) -> tuple[float, float]:
        """One axis: the rate wanted (deg/s, the error's direction, at most ``cap``) and the
        new sum. Within the dead band only the sum acts (it carries the target's own motion);
        the sum stops growing while the rate is at its cap (no wind-up)."""
        s = self.settings
        grown = total + err * dt
        want = (0.0 if abs(err) <= band else s.gain * err) + s.integral * grown
        if abs(want) > cap and abs(grown) > abs(total):
            grown = total  # saturated: accumulating more would only overshoot later
            want = (0.0 if abs(err) <= band else s.gain * err) + s.integral * grown
        return max(-cap, min(cap, want)), grown

    def _let_go(self) -> Command | None:
        if self._last is None:
            return None  # already let go: nothing to send
        self._last, self._last_t = None, None
        self.counts["let_go"] += 1
        return Command(0.0, 0.0)  # once: a gimbal keeps its last rate otherwise


@dataclass(frozen=True)
class GimbalTarget:
    """Which gimbal a camera's session steers: its manager's MAVLink address (the autopilot,
    component 1, by default: ArduPilot and PX4 run the gimbal manager), the gimbal device it
    manages (0: all), and the loop's settings."""

    system: int = 1
    component: int = 1
    device_id: int = 0
    settings: FollowSettings = FollowSettings()
    max_command_hz: float = 30.0


class GimbalFollower:
    """A session's results as Gimbal Protocol v2 rate commands on a MAVLink connection.

    ``send`` sends a pymavlink message as this component, whose (system, component) is
    ``source`` (the camera's); ``target`` is the gimbal manager's (system, component),
    ``gimbal_device_id`` the gimbal it manages (0: all). Call :meth:`take_control` when a
    session starts, then :meth:`on_result` with each result of that session and :meth:`tick`
    between results (the timeout)."""

    def __init__(self, send: Callable[[Any], None], source: tuple[int, int],
                 target: tuple[int, int], *, gimbal_device_id: int = 0,
                 settings: FollowSettings | None = None, max_command_hz: float = 30.0) -> None:
        if not max_command_hz > 0:
            raise ValueError("max_command_hz must be > 0")
        self.send = send
        self.source = source
        self.target = target
        self.gimbal_device_id = gimbal_device_id
        self.controller = FollowController(settings)
        self.min_interval_s = 1.0 / max_command_hz
        self._next_t: float | None = None  # when the next command may go
        self._lock = threading.Lock()  # results and ticks come from different threads
        self.counts: Counter[str] = Counter()

    def take_control(self) -> None:
        """Ask the gimbal manager for primary control (this system and component)."""
        sysid, compid = self.source
        self.send(mav.MAVLink_command_long_message(
            self.target[0], self.target[1], mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, 0,
            sysid, compid, -1, -1, 0, 0, self.gimbal_device_id))
        self.counts["configure"] += 1

    def on_result(self, result: Result, size: tuple[int, int] | None, now: float) -> None:
        """A result of the followed session (``size``: its stream's picture size; None when
        unknown, which lets go)."""
        seen = Observation.of(result, size) if size is not None else Observation(
            (0.0, 0.0, 0.0, 0.0), (0, 0), False)
        with self._lock:
            self._send(self.controller.update(seen, now), now)
            self.counts["results"] += 1  # after its command: a count seen means it is sent

    def tick(self, now: float) -> None:
        """Between results: lets go once the session is silent for ``timeout_s``."""
        with self._lock:
            self._send(self.controller.update(None, now), now)

    def _send(self, cmd: Command | None, now: float) -> None:
        if cmd is None:
            return
        stop = cmd.yaw_dps == 0.0 and cmd.pitch_dps == 0.0 and not self.controller.engaged
        if not stop and self._next_t is not None and now < self._next_t - 1e-6:
            self.counts["held"] += 1  # the rate limit: the next result brings a fresher one
            return
        # one command per interval on the schedule: a result a little late (jitter) does not
        # push the schedule back, and after a pause the next waits half an interval at least
        interval = self.min_interval_s
        self._next_t = now + interval if self._next_t is None else max(
            self._next_t + interval, now + interval / 2)
        nan = float("nan")
        self.send(mav.MAVLink_gimbal_manager_set_pitchyaw_message(
            self.target[0], self.target[1], mav.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME,
            self.gimbal_device_id, nan, nan, math.radians(cmd.pitch_dps),
            math.radians(cmd.yaw_dps)))
        self.counts["stops" if stop else "rates"] += 1
