"""Re-acquisition: where a lost track looks for its target.

A correlation filter only looks inside its search window, so once the target has left the
window (an occlusion long enough for the camera or the target to move, a fast pan, an
out-of-view exit) no amount of waiting brings it back. While the track is not ``tracking``
(:mod:`arcf.state`) the tracker learns nothing, so its filter is still the one that knew the
target. From the frame after the one that lost the track, every frame:

1. **Propose** (:class:`TargetTemplate`): the grey look of the target, kept from a trusted
   frame well before the loss, is matched over one **band** of the frame at a coarse
   resolution (normalised cross-correlation, OpenCV's ``matchTemplate``), the next band on
   the next frame: ``search_bands`` frames sweep the whole frame, and no place of it is out of
   reach. The frame is shrunk so that the template is about ``TEMPLATE_SIDE`` pixels, and the
   frame at most ``MAX_SEARCH_PIXELS``: a bounded cost whatever the frame's size. The band's
   best places are verified on the next frame.
2. **Verify** (the tracker's ``_probe``): at most ``probes`` windows, at the track's scale, are
   correlated with the kept filter and their strength read against the references of the
   frames before the loss (:meth:`arcf.state.TrackMonitor.probe`): the place seen strong on
   the frame before (to confirm it), a promising one seen off its centre (now centred on the
   filter's peak), the band's best, where the target was last tracked. A template is easily
   fooled by anything of the same shape and brightness; the filter, learnt on the target and
   its background, is not.

A place wins when its strength reaches ``reacquire_above`` on two frames in a row, the box's
own is below ``coast_below`` and the place beats it by ``reacquire_margin``: the box jumps
there, the track is ``tracking`` again and the result says ``reacquired``.

Both steps are budgeted per frame (a band, ``probes`` windows), and every pixel they read is
known before the frame arrives, so a lost frame costs about what a tracked one does (it does
not learn), and a caller that decodes frames by region (the service) decodes only the band
and the windows (``ARCFTracker.read_region``).
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

    def _factor(self) -> int:
        k = int(self.shrink)
        if k != self.shrink:
            raise ValueError("a searching template is shrunk by a whole factor (cut(search=True))")
        return k

    def band(self, image_hw: tuple[int, int], index: int, bands: int) -> tuple[int, int]:
        """Band ``index`` of ``bands`` (top to bottom) as source rows ``[top, bottom)``: the
        bands' template placements split the frame's evenly, and each band holds the whole
        template at each of its placements, so the bands together match every placement of
        the whole frame once. ``(0, 0)`` for a frame smaller than the template."""
        k = self._factor()
        th = self.pixels.shape[0]
        placements = image_hw[0] // k - th + 1  # rows of the shrunk frame's score map
        if placements <= 0 or image_hw[1] // k < self.pixels.shape[1]:
            return 0, 0
        index %= bands
        first = placements * index // bands
        last = placements * (index + 1) // bands  # exclusive
        if last <= first:
            return 0, 0
        return first * k, (last + th - 1) * k

    def candidates(self, image: np.ndarray, count: int,
                   rows: tuple[int, int] | None = None) -> list[tuple[float, Point]]:
        """The ``count`` best matches in the source rows ``rows`` (a :meth:`band`; default the
        whole frame), best first, as (score, centre), each at least a template away from the
        better ones (non-maximum suppression). Only those rows of ``image`` are read."""
        k = self._factor()
        # the frame cut to whole k x k blocks: OpenCV's area resize then averages blocks
        top, bottom = rows if rows is not None else (0, image.shape[0])
        top, bottom = top // k * k, min(bottom, image.shape[0]) // k * k
        cols = (image.shape[1] // k) * k
        if bottom - top < k or cols < k:
            return []
        frame = cv2.resize(grey(image[top:bottom, :cols]), (cols // k, (bottom - top) // k),
                           interpolation=cv2.INTER_AREA)
        th, tw = self.pixels.shape
        if frame.shape[0] < th or frame.shape[1] < tw:
            return []
        scores = cv2.matchTemplate(frame, self.pixels, cv2.TM_CCOEFF_NORMED)
        scores = np.nan_to_num(scores, nan=-1.0)
        out: list[tuple[float, Point]] = []
        for _ in range(count):
            i, j = divmod(int(np.argmax(scores)), scores.shape[1])
            score = float(scores[i, j])
            if not math.isfinite(score) or score <= -1.0:
                break
            # centre of the match in the source frame's 1-based coordinates
            out.append((score, (top + (i + th / 2) * self.shrink + 0.5,
                                (j + tw / 2) * self.shrink + 0.5)))
            scores[max(0, i - th):i + th + 1, max(0, j - tw):j + tw + 1] = -1.0
        return out
