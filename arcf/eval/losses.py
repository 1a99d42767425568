"""Losses made from sequences that have none: calibration and test episodes beside the real ones.

The shared sequences never lose their target; three clips do (``data/occlusions``). To test
"lost" and "found again" on more than three episodes, each shared sequence is turned into one
episode of each kind below, on its own real frames. Every kind marks the frames without a
visible target with NaN ground-truth rows, as the benchmarks' annotations do, so the episodes
score exactly like the real ones (``benchmarks/track_state.py``). Each is a different kind of
loss, with a different way back:

* ``cover``: the target, as it moves on, is painted over with the frame's own texture from
  just above it (an occluder the size of the target; it comes back where it went);
* ``cut``: the video cuts to another sequence's frames for a while, then back (a camera
  switch, a link that carried another feed); the target comes back where it went meanwhile;
* ``pan``: the view is a window that follows the target (a gimbal) and slews away from it
  until the target is out of view, holds, and slews back; the target comes back at the view's
  edge and moves to its centre.

Synthetic, so a supplement to the real clips, never a substitute: a cover is cleaner than a
tree, a cut is more abrupt than anything in the air.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

LossKind = Literal["cover", "cut", "pan"]
KINDS: tuple[LossKind, ...] = ("cover", "cut", "pan")

#: the pan's view: this share of the frame on each axis
PAN_VIEW = 0.5
#: frames the pan takes to slew away, and again to slew back
PAN_SLEW = 3
#: a box with less than this share of its area in view counts as out of view (NaN)
PAN_VISIBLE = 0.25


def _read(path: Path) -> np.ndarray:
    frame = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if frame is None:
        raise OSError(f"cannot decode {path}")
    return frame


@dataclass(frozen=True, eq=False)
class Loss:
    """One sequence with one made loss: its frames (decoded on demand, in order) and the ground
    truth ``groundtruth`` ``(N, 4)`` of what is shown, NaN rows where the target is not
    visible."""

    name: str
    kind: LossKind
    groundtruth: np.ndarray
    #: the source sequence's frames and its true boxes ``(N, 4)``, in its own coordinates
    source: tuple[Path, ...]
    truth: np.ndarray
    #: the loss: its first frame and its length (the hold, for a pan)
    start: int
    length: int
    #: the frames a ``cut`` shows instead
    other: tuple[Path, ...] = ()
    #: the ``pan``'s view origin per frame ``(N, 2)``, (x, y) 0-based pixels
    offsets: np.ndarray | None = None

    @property
    def hidden(self) -> np.ndarray:
        """(N,) True where the target is not visible."""
        return ~np.all(np.isfinite(self.groundtruth), axis=1)

    def frames(self) -> Iterator[np.ndarray]:
        """The frames shown, BGR uint8, one per ground-truth row."""
        during = range(self.start, self.start + self.length)
        for k, path in enumerate(self.source):
            frame = _read(path)
            if self.kind == "pan" and self.offsets is not None:
                vh, vw = _view_hw(frame.shape[:2])
                x0, y0 = (int(v) for v in self.offsets[k])
                yield np.ascontiguousarray(frame[y0:y0 + vh, x0:x0 + vw])
            elif self.kind == "cut" and k in during:
                other = _read(self.other[(k - self.start) % len(self.other)])
                yield cv2.resize(other, (frame.shape[1], frame.shape[0]),
                                 interpolation=cv2.INTER_AREA)
            elif self.kind == "cover" and k in during:
                yield _covered(frame, self.truth[k])
            else:
                yield frame


def _covered(frame: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The target's box, grown by 30 % of its size on each side, painted over with the frame's
    own texture from just above it (or grey at the top border)."""
    if not np.all(np.isfinite(box)):
        return frame
    x, y, w, h = box
    x0, y0 = max(int(x - 1 - 0.3 * w), 0), max(int(y - 1 - 0.3 * h), 0)
    x1, y1 = int(x - 1 + 1.3 * w), int(y - 1 + 1.3 * h)
    patch = frame[max(2 * y0 - y1 - 20, 0):max(y0 - 20, 0), x0:x1]
    region = frame[y0:y1, x0:x1]
    region[...] = patch[:region.shape[0], :region.shape[1]] \
        if patch.shape[:2] == region.shape[:2] else 90
    return frame


def covered_frames(paths: Sequence[Path], gt: np.ndarray, start: int,
                   length: int) -> Iterator[np.ndarray]:
    """The frames of ``paths`` with the target (``gt``, ``(N, 4)``) covered for ``length``
    frames from ``start`` (the ``cover`` kind)."""
    for k, path in enumerate(paths):
        frame = _read(path)
        yield _covered(frame, gt[k]) if start <= k < start + length else frame


def _view_hw(frame_hw: tuple[int, int]) -> tuple[int, int]:
    return round(frame_hw[0] * PAN_VIEW), round(frame_hw[1] * PAN_VIEW)


def _pan(gt: np.ndarray, frame_hw: tuple[int, int], start: int,
         length: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The pan's view origins ``(N, 2)`` and the ground truth in view coordinates, or None
    when the frame leaves no room to slew the target out of view."""
    rows, cols = frame_hw
    vh, vw = _view_hw(frame_hw)
    n = len(gt)
    centre = np.column_stack([gt[:, 0] - 1 + gt[:, 2] / 2, gt[:, 1] - 1 + gt[:, 3] / 2])
    follow = centre - [vw / 2, vh / 2]
    # the slew: along the axis with the most room beyond the target, to the frame's far side
    room = {(1, 0): cols - vw - follow[start, 0], (-1, 0): follow[start, 0],
            (0, 1): rows - vh - follow[start, 1], (0, -1): follow[start, 1]}
    direction, _ = max(room.items(), key=lambda kv: kv[1])
    size = gt[min(start, n - 1), 2:]
    need = np.array([vw / 2 + size[0], vh / 2 + size[1]]) * np.abs(direction)
    amount = np.zeros(n)
    for k in range(n):
        t = k - start
        if 0 <= t < PAN_SLEW:
            amount[k] = (t + 1) / PAN_SLEW
        elif PAN_SLEW <= t < PAN_SLEW + length:
            amount[k] = 1.0
        elif PAN_SLEW + length <= t < 2 * PAN_SLEW + length:
            amount[k] = 1.0 - (t - PAN_SLEW - length + 1) / PAN_SLEW
    offsets = follow + amount[:, None] * need * np.array(direction)
    offsets[:, 0] = np.clip(offsets[:, 0], 0, cols - vw)
    offsets[:, 1] = np.clip(offsets[:, 1], 0, rows - vh)
    offsets = np.round(offsets)
    boxes = gt.copy()
    boxes[:, 0] -= offsets[:, 0]
    boxes[:, 1] -= offsets[:, 1]
    # the part of each box in view (1-based: pixels 1..vw), NaN when too little of it
    x0 = np.clip(boxes[:, 0], 1, vw + 1)
    y0 = np.clip(boxes[:, 1], 1, vh + 1)
    x1 = np.clip(boxes[:, 0] + boxes[:, 2], 1, vw + 1)
    y1 = np.clip(boxes[:, 1] + boxes[:, 3], 1, vh + 1)
    inside = (x1 - x0) * (y1 - y0) / np.maximum(boxes[:, 2] * boxes[:, 3], 1e-9)
    out = np.column_stack([x0, y0, x1 - x0, y1 - y0])
    out[~(inside >= PAN_VISIBLE)] = np.nan
    hidden = ~np.all(np.isfinite(out), axis=1)
    if not hidden[start:start + PAN_SLEW + length].any() or hidden[0]:
        return None
    return offsets, out


def make_loss(kind: LossKind, name: str, frames: Sequence[Path], groundtruth: np.ndarray,
              length: int, other: Sequence[Path] = ()) -> Loss | None:
    """``kind`` of loss for ``length`` frames from the middle of a sequence (``frames``, one
    ground-truth row each; ``other``: the frames a ``cut`` cuts to). None when the sequence
    cannot take it (a pan with no room to slew the target out, a cut with nothing to cut to)."""
    gt = np.array(groundtruth, dtype=np.float64)
    frames = tuple(Path(p) for p in frames)
    n = len(frames)
    start = n // 2
    if n < start + length + 2 or length < 1:
        return None
    if kind == "pan":
        hw = _read(frames[0]).shape[:2]
        panned = _pan(gt, (int(hw[0]), int(hw[1])), start, length)
        if panned is None:
            return None
        offsets, view_gt = panned
        return Loss(f"{name}+pan{length}", kind, view_gt, frames, gt, start, length,
                    offsets=offsets)
    if kind == "cut" and not other:
        return None
    shown = gt.copy()
    shown[start:start + length] = np.nan
    return Loss(f"{name}+{kind}{length}", kind, shown, frames, gt, start, length,
                other=tuple(Path(p) for p in other))
