"""A simulated gimbal camera in a world of real pictures, for closing the follow loop in tests
and benchmarks without hardware.

:class:`SimulatedGimbal` is a two-axis gimbal under rate control: each axis reaches its
commanded rate with a first-order lag (the motors), never faster than ``max_rate_dps``, within
its travel. :class:`VirtualCamera` is a camera on it looking at a world picture (a shared
sequence's frame, which spans ``world_hfov_deg``): it sees the ``view_size`` window around the
direction the gimbal points, at ``px_per_deg`` pixels a degree (the world's), sub-pixel
accurately. :func:`run_follow` closes the loop on a sequence in simulated time: the world
moves at the sequence's frame rate, the camera runs at ``rate_hz``, the tracker (any preset)
tracks the views, the controller steers the gimbal, and the true target's offset from the
view's centre is recorded at every frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

import arcf
from arcf.adapters.gimbal import Command, FollowController, FollowSettings, Observation
from arcf.eval import Sequence


@dataclass
class SimulatedGimbal:
    """Yaw and pitch in degrees (pitch positive up, yaw positive to the right)."""

    yaw: float = 0.0
    pitch: float = 0.0
    max_rate_dps: float = 90.0
    lag_s: float = 0.05
    #: the travel each side of the centre: enough for the shared pictures (90 x 51 degrees)
    yaw_travel: float = 45.0
    pitch_travel: float = 26.0
    rate: tuple[float, float] = (0.0, 0.0)  # (yaw, pitch), deg/s
    commanded: tuple[float, float] = (0.0, 0.0)

    def command(self, cmd: Command) -> None:
        self.commanded = (cmd.yaw_dps, cmd.pitch_dps)

    def step(self, dt: float) -> None:
        k = 1.0 - math.exp(-dt / self.lag_s) if self.lag_s > 0 else 1.0
        yaw_rate, pitch_rate = (
            max(-self.max_rate_dps, min(self.max_rate_dps, r + (c - r) * k))
            for r, c in zip(self.rate, self.commanded, strict=True))
        self.rate = (yaw_rate, pitch_rate)
        self.yaw = max(-self.yaw_travel, min(self.yaw_travel, self.yaw + yaw_rate * dt))
        self.pitch = max(-self.pitch_travel, min(self.pitch_travel,
                                                 self.pitch + pitch_rate * dt))


@dataclass(frozen=True)
class VirtualCamera:
    """A ``view_size`` window of a ``world_size`` picture spanning ``world_hfov_deg``."""

    world_size: tuple[int, int]
    view_size: tuple[int, int]
    world_hfov_deg: float = 90.0

    @property
    def px_per_deg(self) -> float:
        return self.world_size[0] / self.world_hfov_deg

    @property
    def hfov_deg(self) -> float:
        return self.view_size[0] / self.px_per_deg

    def centre(self, gimbal: SimulatedGimbal) -> tuple[float, float]:
        """Where the optical axis meets the world picture (0-based pixels)."""
        return (self.world_size[0] / 2 + gimbal.yaw * self.px_per_deg,
                self.world_size[1] / 2 - gimbal.pitch * self.px_per_deg)

    def view(self, world: np.ndarray, gimbal: SimulatedGimbal) -> np.ndarray:
        cx, cy = self.centre(gimbal)
        # getRectSubPix's centre is in pixel-centre coordinates: pixel i spans [i, i + 1)
        return cv2.getRectSubPix(world, self.view_size, (cx - 0.5, cy - 0.5))

    def to_view(self, box: np.ndarray, gimbal: SimulatedGimbal) -> np.ndarray:
        """A 1-based world box in the view's 1-based pixels."""
        cx, cy = self.centre(gimbal)
        out = np.array(box, dtype=float)
        out[0] += self.view_size[0] / 2 - cx
        out[1] += self.view_size[1] / 2 - cy
        return out


@dataclass
class FollowRun:
    """A closed loop's record, one entry per camera frame."""

    t: list[float] = field(default_factory=list)
    #: the true target's centre offset from the view's centre, as shares of the view (x, y)
    offset: list[tuple[float, float]] = field(default_factory=list)
    #: the tracker's box's centre offset (what the controller sees), likewise
    seen: list[tuple[float, float]] = field(default_factory=list)
    state: list[str] = field(default_factory=list)
    command: list[Command | None] = field(default_factory=list)
    gimbal: list[tuple[float, float]] = field(default_factory=list)

    def offsets(self) -> np.ndarray:
        return np.array(self.offset)


def run_follow(seq: Sequence, *, rate_hz: float, preset: str = "arcf-h",
               overrides: Mapping[str, Any] | None = None,
               settings: FollowSettings | None = None, view_size: tuple[int, int] = (640, 360),
               world_hfov_deg: float = 90.0, start: tuple[float, float] = (0.25, -0.2),
               seconds: float | None = None,
               world_edit: Callable[[int, np.ndarray], np.ndarray] | None = None) -> FollowRun:
    """Close the loop on ``seq`` for ``seconds`` (default: the sequence) at ``rate_hz``.

    The gimbal starts pointed so that the target sits at ``start`` (shares of the view,
    right and down positive) and the tracker is initialised there on the ground truth box;
    ``world_edit(k, picture)`` may change the world picture of frame k (an occlusion);
    ``overrides`` go to the preset (``create_tracker``)."""
    fps = 10.0  # UAV123@10fps, DTB70 and UAVDT as shared: 10 pictures a second
    first = seq.read_frame(0)
    world_size = (first.shape[1], first.shape[0])
    cam = VirtualCamera(world_size, view_size, world_hfov_deg)
    settings = settings or FollowSettings(hfov_deg=cam.hfov_deg)
    gt = np.asarray(seq.groundtruth, dtype=float)
    x, y, w, h = gt[0]
    tx, ty = x - 1 + w / 2, y - 1 + h / 2  # the target's centre, 0-based world pixels
    gimbal = SimulatedGimbal()
    gimbal.yaw = (tx - start[0] * view_size[0] - world_size[0] / 2) / cam.px_per_deg
    gimbal.pitch = -(ty - start[1] * view_size[1] - world_size[1] / 2) / cam.px_per_deg
    tracker = arcf.create_tracker(preset, **dict(overrides or {}))
    controller = FollowController(settings)
    run = FollowRun()
    dt = 1.0 / rate_hz
    last = len(seq) - 1 if seconds is None else min(len(seq) - 1, int(seconds * fps))
    n = int(last / fps * rate_hz)
    for k in range(n + 1):
        t = k * dt
        i = min(last, int(t * fps + 1e-9))
        world = seq.read_frame(i)
        if world_edit is not None:
            world = world_edit(i, world)
        view = cam.view(world, gimbal)
        if k == 0:
            box = cam.to_view(gt[0], gimbal)
            r = tracker.init(view, (float(box[0]), float(box[1]), float(box[2]),
                                    float(box[3])))
            state = "initialized"
        else:
            r = tracker.update(view)
            state = r.state.value
        seen = Observation((float(r.box[0]), float(r.box[1]), float(r.box[2]),
                            float(r.box[3])), view_size,
                           k == 0 or r.state.value == "tracking")
        cmd = controller.update(seen, t)
        if cmd is not None:
            gimbal.command(cmd)
        truth = cam.to_view(gt[i], gimbal)
        run.t.append(t)
        run.offset.append(((truth[0] - 1 + truth[2] / 2) / view_size[0] - 0.5,
                           (truth[1] - 1 + truth[3] / 2) / view_size[1] - 0.5))
        run.seen.append(((r.box[0] - 1 + r.box[2] / 2) / view_size[0] - 0.5,
                         (r.box[1] - 1 + r.box[3] / 2) / view_size[1] - 0.5))
        run.state.append(state)
        run.command.append(cmd)
        run.gimbal.append((gimbal.yaw, gimbal.pitch))
        gimbal.step(dt)
    return run
