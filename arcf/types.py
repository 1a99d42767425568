"""What every tracker of the library shares: the box, the per-frame result, the ``init`` /
``update`` protocol, and the checks of a caller's frame and box.

Coordinates: boxes are ``(x, y, w, h)`` in the datasets' 1-based pixel frame (the pixel at
array index [0, 0] has coordinates (1, 1)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .errors import InvalidBoxError, InvalidFrameError
from .region import Region, RegionFrame
from .state import TrackState

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class TrackResult:
    """What the tracker reports for one frame.

    ``peak`` is the response maximum at the sub-cell peak and ``psr`` the peak-to-sidelobe ratio
    of the response map: both are low when the target is lost or occluded, but neither is a
    probability. ``aberrance`` is the response-map difference of Eq. 2 (Euclidean norm of the
    previous map, shifted onto the current peak, minus the current map); ``aberrance_release``
    is the same difference measured as the release does (largest singular value), comparable
    with the published ``map_diff`` files. Both are 0 on the first frame.

    ``state`` is what the tracker makes of its response against the track's recent trusted
    frames: ``tracking``, ``coasting`` (probably hidden: the box is a guess) or ``lost``
    (:mod:`arcf.state`); ``confidence`` the calibrated estimate that the box overlaps the
    target at all (IoU > 0), from those signals, the state and the box's look. The first frame
    of a (re)initialisation is ``tracking`` with confidence 1: its box was given.
    """

    box: Box
    peak: float
    psr: float
    aberrance: float
    aberrance_release: float
    scale: float
    frame_index: int
    confidence: float = 1.0
    state: TrackState = TrackState.TRACKING
    #: True on the frame where a lost track found its target again (:mod:`arcf.reacquire`).
    reacquired: bool = False


def validate_frame(frame: Any) -> None:
    """Raise :class:`InvalidFrameError` unless ``frame`` is a uint8 HxW, HxWx1 or HxWx3 array."""
    if not isinstance(frame, np.ndarray):
        raise InvalidFrameError(f"frame must be a numpy array, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise InvalidFrameError(f"frame must be uint8 (OpenCV BGR or gray), got {frame.dtype}")
    if frame.ndim not in (2, 3) or (frame.ndim == 3 and frame.shape[2] not in (1, 3)):
        raise InvalidFrameError(
            f"frame must be HxW (gray) or HxWx3 (BGR), got shape {tuple(frame.shape)}"
        )
    if frame.shape[0] < 2 or frame.shape[1] < 2:
        raise InvalidFrameError(f"frame is too small: {frame.shape[1]}x{frame.shape[0]} pixels")


def validate_box(box: Any, image_hw: tuple[int, int]) -> Box:
    """Check an ``(x, y, w, h)`` box against a frame; raise :class:`InvalidBoxError` if absurd.

    A box may stick out of the frame (patches replicate the border), but it must overlap it, be
    at least one pixel in each direction, and not be more than 4x the frame in either direction.
    """
    if isinstance(box, (str, bytes, bytearray)):
        raise InvalidBoxError(f"box must be four numbers (x, y, w, h), got the string {box!r}")
    try:
        values = [float(v) for v in box]
    except (TypeError, ValueError) as exc:
        raise InvalidBoxError(f"box must be four numbers (x, y, w, h), got {box!r}") from exc
    if len(values) != 4:
        raise InvalidBoxError(f"box must be four numbers (x, y, w, h), got {len(values)} values")
    x, y, w, h = values
    if not all(math.isfinite(v) for v in values):
        raise InvalidBoxError(f"box has a NaN or infinite value: {tuple(values)}")
    if w < 1 or h < 1:
        raise InvalidBoxError(f"box must be at least 1x1 pixel, got w={w:g}, h={h:g}")
    ih, iw = image_hw
    if x - 1 >= iw or y - 1 >= ih or x - 1 + w <= 0 or y - 1 + h <= 0:
        raise InvalidBoxError(
            f"box {tuple(values)} lies entirely outside the {iw}x{ih} frame "
            "(boxes use the datasets' 1-based pixel coordinates)"
        )
    if w > 4 * iw or h > 4 * ih:
        raise InvalidBoxError(f"box {tuple(values)} is more than 4x the {iw}x{ih} frame")
    return x, y, w, h


class Tracker(Protocol):
    """What every preset's tracker is: the field's ``init`` / ``update`` pair."""

    def init(self, frame: np.ndarray, box: Box | Any) -> TrackResult: ...

    def update(self, frame: np.ndarray | RegionFrame) -> TrackResult: ...

    def read_region(self) -> Region | None:
        """The pixels the next ``update`` reads (:mod:`arcf.region`); None: the whole frame."""
        ...
