"""Image patches around the target, padded by replicating the border as the release does.

Positions are (row, col) in 1-based pixel coordinates (the datasets' and MATLAB's frame), so the
release's rounding rules carry over unchanged; conversion to array indices happens here only.
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def matlab_round(v: float) -> int:
    """MATLAB's ``round``: halves away from zero (Python's ``round`` goes to even)."""
    return math.floor(v + 0.5) if v >= 0 else -math.floor(-v + 0.5)


def resize_auto(patch: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """``mexResize(..., 'auto')``: area interpolation when shrinking, bilinear when enlarging."""
    h, w = patch.shape[:2]
    oh, ow = out_hw
    if (h, w) == (oh, ow):
        return patch
    interp = cv2.INTER_AREA if oh * ow < h * w else cv2.INTER_LINEAR
    out = cv2.resize(patch, (ow, oh), interpolation=interp)
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

    1-based rows ``floor(pos) + (1..s) - floor(s/2)``, so the array index of the first row is
    ``floor(pos) - floor(s/2)``.
    """
    sh, sw = (s if s >= 1 else 2 for s in size)
    top = math.floor(pos[0]) - sh // 2
    left = math.floor(pos[1]) - sw // 2
    return resize_auto(crop_replicate(image, top, left, sh, sw), out_hw)


def eco_patch(
    image: np.ndarray,
    pos: tuple[float, float],
    sample_hw: tuple[float, float],
    out_hw: tuple[int, int],
) -> np.ndarray:
    """ECO's ``sample_patch`` (used by ARCF-HC): like :func:`bacf_patch` but it first decimates
    the image by an integer factor when the window is more than ~2x the output, and centres with
    ``floor((s+1)/2)``. The decimation is done on indices, without touching the whole image.
    """
    pr, pc = math.floor(pos[0]), math.floor(pos[1])
    resize_factor = min(sample_hw[0] / out_hw[0], sample_hw[1] / out_hw[1])
    df = max(math.floor(resize_factor - 0.1), 1)
    sh_f, sw_f = sample_hw
    ih, iw = image.shape[:2]
    if df > 1:
        osr, osc = (pr - 1) % df, (pc - 1) % df
        pr, pc = (pr - 1 - osr) // df + 1, (pc - 1 - osc) // df + 1
        sh_f, sw_f = sh_f / df, sw_f / df
    sh, sw = max(matlab_round(sh_f), 2), max(matlab_round(sw_f), 2)
    top = pr - (sh + 1) // 2  # 0-based index in the (possibly decimated) image
    left = pc - (sw + 1) // 2
    if df > 1:
        n_r = len(range(osr, ih, df))
        n_c = len(range(osc, iw, df))
        rows = osr + df * np.clip(np.arange(top, top + sh), 0, n_r - 1)
        cols = osc + df * np.clip(np.arange(left, left + sw), 0, n_c - 1)
        patch = image[np.ix_(rows, cols)]
    else:
        patch = crop_replicate(image, top, left, sh, sw)
    return resize_auto(patch, out_hw)
