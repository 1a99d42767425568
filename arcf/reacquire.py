"""Re-acquisition: where a lost track looks for its target.

A correlation filter only looks inside its search window, so once the target has left the
window (an occlusion long enough for the camera or the target to move, a fast pan, an
out-of-view exit) no amount of waiting brings it back. While the track is not ``tracking``
(:mod:`arcf.state`) the tracker learns nothing, so its filter is still the one that knew the
target. Once the track is ``lost``, every frame:

1. **Propose** (:class:`TargetTemplate`): the grey look of the target, kept from a trusted
   frame well before the loss, is matched over the **whole frame** at a coarse resolution
   (normalised cross-correlation, OpenCV's ``matchTemplate``); the best few places, apart
   from each other, are candidates. One pass over a frame shrunk so that the template is
   about ``TEMPLATE_SIDE`` pixels, and the frame at most ``MAX_SEARCH_PIXELS``: a bounded
   cost whatever the frame's size, and no place of the frame is out of reach.
2. **Verify** (the tracker's ``_probe``): at each candidate, and where the target was last
   tracked, one window at the track's scale is correlated with the kept filter and its
   strength read against the references of the frames before the loss
   (:meth:`arcf.state.TrackMonitor.probe`). A template is easily fooled by anything of the
   same shape and brightness; the filter, learnt on the target and its background, is not.

A place wins when its strength reaches ``reacquire_above`` on two frames in a row, the box's
own is below ``coast_below`` and the place beats it by ``reacquire_margin``: the box jumps
there, the track is ``tracking`` again and the result says ``reacquired``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: (row, col) in the datasets' 1-based pixel frame
Point = tuple[float, float]

#: The template's shorter side after shrinking, pixels: enough detail to tell a shape, few
#: enough pixels for one pass over the frame to cost about a tracked window.
TEMPLATE_SIDE = 12
#: The most pixels of a shrunk frame the template is matched over: a frame larger than this
#: is shrunk further (and the template with it), so that a lost frame's search costs about the
#: same on a 4K frame as on a 720p one (1280 x 720 shrunk 2.4 times).
MAX_SEARCH_PIXELS = 160_000
#: Trusted frames between two refreshes of the kept template, and how many are kept: the one
#: used after a loss is the oldest, taken before any slow onset of the occlusion.
TEMPLATE_EVERY = 5
TEMPLATE_KEEP = 3


def grey(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 from a BGR or single-channel frame."""
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image.reshape(image.shape[0], image.shape[1])


@dataclass(frozen=True)
class TargetTemplate:
    """The target's grey look at a trusted frame, shrunk by ``shrink`` (source pixels per
    template pixel)."""

    #: (h, w) uint8 at the shrunk resolution
    pixels: np.ndarray
    shrink: float

    @classmethod
    def cut(cls, image: np.ndarray, centre: Point, size_hw: tuple[float, float],
            search: bool = True) -> TargetTemplate:
        """The box of ``size_hw`` source pixels around ``centre``, clipped to the frame and
        shrunk so that its shorter side is about ``TEMPLATE_SIDE`` pixels (never enlarged);
        for a template that will search frames (``search``), more if the frame shrunk as much
        would exceed ``MAX_SEARCH_PIXELS``."""
        rows, cols = image.shape[:2]
        h, w = max(size_hw[0], 2.0), max(size_hw[1], 2.0)
        shrink = max(1.0, min(h, w) / TEMPLATE_SIDE)
        if search:  # a whole factor: OpenCV's area resize of the frame is 10x faster so
            shrink = float(math.ceil(max(shrink, math.sqrt(rows * cols / MAX_SEARCH_PIXELS))))
        r0 = int(np.clip(round(centre[0] - 1 - h / 2), 0, rows - 2))
        c0 = int(np.clip(round(centre[1] - 1 - w / 2), 0, cols - 2))
        r1 = int(np.clip(round(centre[0] - 1 + h / 2), r0 + 2, rows))
        c1 = int(np.clip(round(centre[1] - 1 + w / 2), c0 + 2, cols))
        patch = grey(image[r0:r1, c0:c1])
        out_hw = (max(2, round(patch.shape[0] / shrink)), max(2, round(patch.shape[1] / shrink)))
        small = cv2.resize(patch, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_AREA)
        return cls(small, shrink)

    def similarity(self, image: np.ndarray, centre: Point, size_hw: tuple[float, float]) -> float:
        """The grey look of the box of ``size_hw`` around ``centre`` against this template:
        normalised cross-correlation at the template's size, in [-1, 1] (0 for a box outside
        the frame or of one flat grey)."""
        rows, cols = image.shape[:2]
        h, w = max(size_hw[0], 2.0), max(size_hw[1], 2.0)
        # plain ints (every frame: NumPy's scalar clipping would cost more than the NCC)
        r0 = min(max(round(centre[0] - 1 - h / 2), 0), rows)
        c0 = min(max(round(centre[1] - 1 - w / 2), 0), cols)
        r1 = min(max(round(centre[0] - 1 + h / 2), 0), rows)
        c1 = min(max(round(centre[1] - 1 + w / 2), 0), cols)
        if r1 - r0 < 2 or c1 - c0 < 2:
            return 0.0
        th, tw = self.pixels.shape
        box = cv2.resize(grey(image[r0:r1, c0:c1]), (tw, th), interpolation=cv2.INTER_AREA)
        score = float(cv2.matchTemplate(box, self.pixels, cv2.TM_CCOEFF_NORMED)[0, 0])
        return score if math.isfinite(score) else 0.0

    def candidates(self, image: np.ndarray, count: int) -> list[tuple[float, Point]]:
        """The ``count`` best matches over the whole frame, best first, as (score, centre),
        each at least a template away from the better ones (non-maximum suppression)."""
        k = int(self.shrink)
        if k != self.shrink:
            raise ValueError("a searching template is shrunk by a whole factor (cut(search=True))")
        # the frame cut to whole k x k blocks: OpenCV's area resize then averages blocks
        rows, cols = (image.shape[0] // k) * k, (image.shape[1] // k) * k
        if rows < k or cols < k:
            return []
        frame = cv2.resize(grey(image[:rows, :cols]), (cols // k, rows // k),
                           interpolation=cv2.INTER_AREA)
        th, tw = self.pixels.shape
        if frame.shape[0] < th or frame.shape[1] < tw:
            return []
        scores = cv2.matchTemplate(frame, self.pixels, cv2.TM_CCOEFF_NORMED)
        scores = np.nan_to_num(scores, nan=-1.0)
        out: list[tuple[float, Point]] = []
        for _ in range(count):
            k = int(np.argmax(scores))
            i, j = divmod(k, scores.shape[1])
            score = float(scores[i, j])
            if not math.isfinite(score) or score <= -1.0:
                break
            # centre of the match in the source frame's 1-based coordinates
            out.append((score, ((i + th / 2) * self.shrink + 0.5,
                                (j + tw / 2) * self.shrink + 0.5)))
            scores[max(0, i - th):i + th + 1, max(0, j - tw):j + tw + 1] = -1.0
        return out
