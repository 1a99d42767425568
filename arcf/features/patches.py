"""Image patches around the target, padded by replicating the border as the release does.

Positions are (row, col) in 1-based pixel coordinates (the datasets' and MATLAB's frame), so the
release's rounding rules carry over unchanged; conversion to array indices happens here only.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .resize import resize_area


def matlab_round(v: float) -> int:
    """MATLAB's ``round``: halves away from zero (Python's ``round`` goes to even)."""
    return math.floor(v + 0.5) if v >= 0 else -math.floor(-v + 0.5)


def resize_auto(patch: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """The release's ``mexResize(patch, out_hw, 'auto')``: bilinear or area interpolation.

    The rule is the release's, not "shrink means area": linear interpolation when the requested
    number of *columns* exceeds the patch's number of *rows*, area otherwise. On the square
    windows of the translation filters both rules agree; on the DSST scale filter's non-square
    samples (e.g. a 48x22 window resized to 32x15) they do not, and which one is used decides
    whether ARCF-HC's boxes match the release's on truck4_1 after frame 34 (reference notes,
    detail 8).
    """
    h, w = patch.shape[:2]
    oh, ow = out_hw
    if (h, w) == (oh, ow):
        return patch
    if ow <= h:
        return resize_area(patch, out_hw)
    out = cv2.resize(patch, (ow, oh), interpolation=cv2.INTER_LINEAR)
    if out.ndim < patch.ndim:  # cv2 drops a trailing singleton channel
        out = out[..., None]
    return out


def crop_replicate(image: np.ndarray, top: int, left: int, h: int, w: int) -> np.ndarray:
    """The (h, w) window with top-left array index (top, left), border-replicated where it leaves
    the image. A window entirely outside the image replicates the nearest edge pixels."""
    ih, iw = image.shape[:2]
    if top >= 0 and left >= 0 and top + h <= ih and left + w <= iw:
        return image[top : top + h, left : left + w]
    r0, r1 = max(top, 0), min(top + h, ih)
    c0, c1 = max(left, 0), min(left + w, iw)
    if r0 < r1 and c0 < c1:
        inner = image[r0:r1, c0:c1]
        out = cv2.copyMakeBorder(
            inner, r0 - top, top + h - r1, c0 - left, left + w - c1, cv2.BORDER_REPLICATE
        )
        if out.ndim < image.ndim:
            out = out[..., None]
        return out
    rows = np.clip(np.arange(top, top + h), 0, ih - 1)
    cols = np.clip(np.arange(left, left + w), 0, iw - 1)
    return image[np.ix_(rows, cols)]


def bacf_patch(
    image: np.ndarray, pos: tuple[float, float], size: tuple[int, int], out_hw: tuple[int, int]
) -> np.ndarray:
    """BACF's ``get_pixels``: a ``size`` window around ``pos`` resized to ``out_hw``.

    Both trackers of the release sample this way (ARCF-HC too, although it is built on ECO's
    code: it does not use ECO's ``sample_patch`` with its integer pre-decimation, whose windows
    differ by up to 156 grey levels on boat1; reference notes, detail 6).

    1-based rows ``floor(pos) + (1..s) - floor(s/2)``, so the array index of the first row is
    ``floor(pos) - floor(s/2)``.
    """
    sh, sw = (s if s >= 1 else 2 for s in size)
    top = math.floor(pos[0]) - sh // 2
    left = math.floor(pos[1]) - sw // 2
    return resize_auto(crop_replicate(image, top, left, sh, sw), out_hw)
