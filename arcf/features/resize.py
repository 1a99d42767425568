"""OpenCV's ``INTER_AREA`` shrink, bit for bit, without its store-to-load dependency chain.

The release samples every window with ``mexResize`` (OpenCV's ``resize``), and ARCF-H cuts six
windows per frame; on a large target each is a ~1100x1100 crop shrunk to 200x200, 5-6 ms apiece
in OpenCV, half of the tracker's time (docs/results-speed.md). OpenCV's area path
(``ResizeArea_Invoker``) is scalar code whose inner statement ``buf[dx] += S[sx] * alpha``
re-reads the value it stored one iteration earlier, so it runs at the latency of a store, a load
and an add per source pixel and channel.

This module computes the same sums in the same order with the same float32 roundings, so the
result is identical (checked against ``cv2.resize`` in tests/arcf/test_resize.py): each
destination column's partial sum lives in a register while its source pixels are added, and
several source rows are summed side by side so that the additions of different rows overlap.
Only the non-integer shrink is done here; integer ratios (OpenCV's separate integer "fast area"
path) and enlargements go to ``cv2.resize`` unchanged.

OpenCV's algorithm (``computeResizeAreaTab`` + ``ResizeArea_Invoker``), with ``scale = src /
dst`` in double precision: destination pixel ``d`` covers source interval ``[d scale, (d + 1)
scale)``; each source pixel it touches gets weight ``overlap / min(scale, src - d scale)``,
rounded to float32. Rows: every source row is first reduced horizontally (float32 sums of
``pixel * weight`` in increasing source column), then the destination row is ``beta_1 row_1``
plus ``beta_2 row_2`` ... (float32, in increasing source row), and finally rounded half to even
and saturated to 0..255.
"""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from .._jit import kernel

__all__ = ["resample_area", "resample_area_windows", "resize_area", "resize_area_windows"]

_DBL_EPSILON = 2.220446049250313e-16


@lru_cache(maxsize=256)
def _area_table(src: int, dst: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``computeResizeAreaTab`` for one axis, grouped by destination pixel.

    Returns ``start`` (int64, ``dst + 1``): destination pixel ``d`` reads table entries
    ``start[d] .. start[d + 1] - 1``; ``index`` (int64): the source pixel of each entry, and
    ``alpha`` (float32): its weight. Entries are in OpenCV's order (increasing source pixel).
    Cached: a tracked target's windows come back to the same few sizes.
    """
    out = _area_entries(src, dst)
    for a in out:
        a.setflags(write=False)
    return out


@kernel
def _area_entries(src, dst):  # pragma: no cover - compiled
    """``_area_table``'s arithmetic, OpenCV's in double precision step by step (compiled: the
    interpreted loop took 0.7 ms per new window size, ~0.1 ms per ARCF-H frame on a target
    that keeps changing size)."""
    scale = 1.0 / (dst / src)  # OpenCV: scale_x = 1. / inv_scale_x, inv_scale_x = dst / src
    start = np.zeros(dst + 1, np.int64)
    index = np.empty(dst * (int(scale) + 3), np.int64)  # at most ceil(scale) + 1 per pixel
    alpha = np.empty(index.size, np.float32)
    k = 0
    for d in range(dst):
        fs1 = d * scale
        fs2 = fs1 + scale
        cell = min(scale, src - fs1)
        s1, s2 = math.ceil(fs1), math.floor(fs2)
        s2 = min(s2, src - 1)
        s1 = min(s1, s2)
        if s1 - fs1 > 1e-3:
            index[k] = s1 - 1
            alpha[k] = np.float32((s1 - fs1) / cell)
            k += 1
        for s in range(s1, s2):
            index[k] = s
            alpha[k] = np.float32(1.0 / cell)
            k += 1
        if fs2 - s2 > 1e-3:
            index[k] = s2
            alpha[k] = np.float32(min(min(fs2 - s2, 1.0), cell) / cell)
            k += 1
        start[d + 1] = k
    return start, index[:k].copy(), alpha[:k].copy()


def resize_area(image: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """``cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)``, bit for bit.

    ``image`` is ``(H, W)`` or ``(H, W, C)`` uint8 (a view is fine); the result has the same
    number of dimensions (unlike OpenCV, a trailing singleton channel is kept).
    """
    h, w = image.shape[:2]
    oh, ow = out_hw
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or not _kernel_shrink(h, w, out_hw):
        return _opencv(image, out_hw)
    cn = 1 if image.ndim == 2 else image.shape[2]
    # Column-major source: row r of the transposed (W C, H) matrix is one source column and
    # channel, so the horizontal sums run along contiguous memory, all source rows at once.
    columns = cv2.transpose(image.reshape(h, w * cn))
    ystart, yindex, yalpha = _area_table(h, oh)
    xstart, xindex, xalpha = _area_table(w, ow)
    out = np.empty((oh, ow, cn), np.uint8)
    _resize_area_u8(columns, cn, ystart, yindex, yalpha, xstart, xindex, xalpha, out)
    return out if image.ndim == 3 else out[..., 0]


def _kernel_shrink(h: int, w: int, out_hw: tuple[int, int]) -> bool:
    """Whether OpenCV shrinks ``(h, w)`` to ``out_hw`` by its general area path (the kernel's):
    a shrink along both axes that is not by whole factors (OpenCV's integer "fast" path)."""
    oh, ow = out_hw
    if oh < 1 or ow < 1:
        return False
    sx, sy = 1.0 / (ow / w), 1.0 / (oh / h)  # OpenCV's scale_x, scale_y
    integer = abs(sx - round(sx)) < _DBL_EPSILON and abs(sy - round(sy)) < _DBL_EPSILON
    return sx >= 1 and sy >= 1 and not integer


def resize_area_windows(
    image: np.ndarray, windows: list[tuple[int, int, int, int]], out_hw: tuple[int, int]
) -> np.ndarray:
    """``resize_area`` of several windows ``(top, left, h, w)`` of one ``(H, W, C)`` uint8 image,
    each border-replicated where it leaves the image (as ``crop_replicate`` would cut it).

    The same result as cutting and resizing each window on its own, bit for bit, with the
    image transposed once for all of them (the DSST scale filter cuts 33 nested windows of one
    region twice a frame; transposing each was a third of their cost). Windows leaving the
    image are not copied with a replicated border: their area tables point at the edge pixel
    instead, which reads the same values (a replicated row's horizontal sums are the edge
    row's, bit for bit), so only the part inside the image is transposed. Returns ``(N, oh,
    ow, C)``.
    """
    height, width, cn = image.shape
    oh, ow = out_hw
    out = np.empty((len(windows), oh, ow, cn), np.uint8)
    kernel_windows = []
    for i, (top, left, h, w) in enumerate(windows):
        if _kernel_shrink(h, w, out_hw):
            kernel_windows.append(i)
        else:  # OpenCV's own paths (whole-factor shrinks, enlargements) on the window's pixels
            rows = np.clip(np.arange(top, top + h), 0, height - 1)
            cols = np.clip(np.arange(left, left + w), 0, width - 1)
            out[i] = _opencv(image[np.ix_(rows, cols)], out_hw)
    if not kernel_windows:
        return out
    # the image part the windows read: their cover, clamped to at least one row and column
    r0 = _clamp(min(windows[i][0] for i in kernel_windows), 0, height - 1)
    r1 = _clamp(max(windows[i][0] + windows[i][2] for i in kernel_windows), r0 + 1, height)
    c0 = _clamp(min(windows[i][1] for i in kernel_windows), 0, width - 1)
    c1 = _clamp(max(windows[i][1] + windows[i][3] for i in kernel_windows), c0 + 1, width)
    columns = cv2.transpose(image[r0:r1, c0:c1].reshape(r1 - r0, (c1 - c0) * cn))
    for i in kernel_windows:
        top, left, h, w = windows[i]
        ystart, yindex, yalpha = _area_table(h, oh)
        xstart, xindex, xalpha = _area_table(w, ow)
        rs, re = _inside(top, h, r0, r1)
        cs, ce = _inside(left, w, c0, c1)
        if rs != top or re != top + h:  # rows outside read the edge row
            yindex = _read_only(np.clip(yindex + (top - rs), 0, re - rs - 1))
        if cs != left or ce != left + w:
            xindex = _read_only(np.clip(xindex + (left - cs), 0, ce - cs - 1))
        view = columns[(cs - c0) * cn: (ce - c0) * cn, rs - r0: re - r0]
        _resize_area_u8(view, cn, ystart, yindex, yalpha, xstart, xindex, xalpha, out[i])
    return out


def _read_only(a: np.ndarray) -> np.ndarray:
    """As the cached tables are: one compiled signature of the kernel for both."""
    a.setflags(write=False)
    return a


def _clamp(v: int, lo: int, hi: int) -> int:
    return min(max(v, lo), hi)


def _inside(start: int, size: int, lo: int, hi: int) -> tuple[int, int]:
    """The pixels ``[s, e)`` of ``[start, start + size)`` inside ``[lo, hi)``; the nearest
    edge pixel when none is."""
    s = _clamp(start, lo, hi - 1)
    return s, _clamp(start + size, s + 1, hi)


def resample_area(
    image: np.ndarray, origin: tuple[float, float], extent: tuple[float, float],
    out_hw: tuple[int, int],
) -> np.ndarray:
    """Area (box) resampling of a window with fractional position and size.

    The window starts at ``origin`` (row, col) and spans ``extent`` (rows, cols) in ``image``'s
    pixel units, both possibly fractional; output pixel ``d`` is the mean of the image over its
    share ``[o + d e / n, o + (d + 1) e / n)``, each source pixel weighted by its overlap (the
    same arithmetic as ``resize_area``, with OpenCV's float32 sums and rounding). Parts of the
    window outside the image read the nearest edge pixel. ``image`` is ``(H, W, C)`` uint8;
    returns ``(oh, ow, C)`` uint8.

    Why: the "pyramid" sampler reads a window from an image already halved ``k`` times, where
    its borders fall between pixels; box weights there keep the result an area average of the
    window, which bilinear interpolation at a shrink of up to 2 is not (it skips pixels).
    """
    return resample_area_windows(image, [(origin, extent)], out_hw)[0]


def resample_area_windows(
    image: np.ndarray, windows: list[tuple[tuple[float, float], tuple[float, float]]],
    out_hw: tuple[int, int],
) -> np.ndarray:
    """``resample_area`` of several ``(origin, extent)`` windows of one image, ``(N, oh, ow,
    C)``, with the image transposed once for all of them (as ``resize_area_windows``)."""
    h, w, cn = image.shape
    oh, ow = out_hw
    columns = cv2.transpose(np.ascontiguousarray(image).reshape(h, w * cn))
    out = np.empty((len(windows), oh, ow, cn), np.uint8)
    for i, (origin, extent) in enumerate(windows):
        ystart, yindex, yalpha = _box_table(origin[0], extent[0], h, oh)
        xstart, xindex, xalpha = _box_table(origin[1], extent[1], w, ow)
        _resize_area_u8(columns, cn, ystart, yindex, yalpha, xstart, xindex, xalpha, out[i])
    return out


@kernel
def _box_table(origin, extent, src, dst):  # pragma: no cover - compiled
    """``_area_table``'s layout for a window ``[origin, origin + extent)`` of ``src`` pixels.

    Source pixels outside ``0 .. src - 1`` are clamped to the edge (replicated border).
    """
    cell = extent / dst
    count = 0
    for d in range(dst):
        lo, hi = origin + d * cell, origin + (d + 1) * cell
        count += math.ceil(hi) - math.floor(lo)
    start = np.zeros(dst + 1, np.int64)
    index = np.empty(count, np.int64)
    alpha = np.empty(count, np.float32)
    k = 0
    for d in range(dst):
        lo, hi = origin + d * cell, origin + (d + 1) * cell
        for s in range(math.floor(lo), math.ceil(hi)):
            overlap = min(hi, s + 1.0) - max(lo, float(s))
            if overlap > 1e-9:
                index[k] = min(max(s, 0), src - 1)
                alpha[k] = np.float32(overlap / cell)
                k += 1
        start[d + 1] = k
    return start, index[:k], alpha[:k]


def _opencv(image: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    out = cv2.resize(image, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_AREA)
    return out[..., None] if out.ndim < image.ndim else out


#: Destination columns (and channels) whose horizontal sums are computed before they are
#: stored together; see ``_resize_area_u8``.
_COLUMN_GROUP = 16


@kernel
def _resize_area_u8(
    columns, cn, ystart, yindex, yalpha, xstart, xindex, xalpha, out
):  # pragma: no cover - compiled
    """The kernel: transposed source ``(W C, H)`` uint8 -> ``(oh, ow, C)`` uint8.

    First the horizontal sums of every source row (OpenCV's ``buf``), one destination column
    and channel at a time, vectorised over the rows; then each destination row is OpenCV's
    vertical sum of those rows, vectorised along the row, rounded half to even and saturated.

    The horizontal sums of ``_COLUMN_GROUP`` destination columns are computed into a small
    buffer and then stored into the row-major ``rows`` together, 64 contiguous bytes per source
    row: stored one column at a time, each value touched its own cache line, which cost more
    than the arithmetic (1100x1100 -> 200x200: 1.26 -> 0.69 ms). Two source columns are added
    per pass (``(row + s1 a1) + s2 a2``, the same float32 operations in the same order), which
    halves the passes over the partial sums (-> 0.63 ms).
    """
    oh, ow, _ = out.shape
    h = columns.shape[1]
    width = ow * cn
    rows = np.empty((h, width), np.float32)  # the horizontally reduced source rows
    group = np.empty((_COLUMN_GROUP, h), np.float32)
    for q0 in range(0, width, _COLUMN_GROUP):
        n_group = min(_COLUMN_GROUP, width - q0)
        for j in range(n_group):
            dx, c = divmod(q0 + j, cn)
            _horizontal_sum(columns, cn, c, xindex, xalpha, xstart[dx], xstart[dx + 1],
                            group[j])
        if n_group == _COLUMN_GROUP:  # a constant trip count: the stores vectorise
            for r in range(h):
                for j in range(_COLUMN_GROUP):
                    rows[r, q0 + j] = group[j, r]
        else:
            for r in range(h):
                for j in range(n_group):
                    rows[r, q0 + j] = group[j, r]
    acc = np.empty(width, np.float32)
    flat = out.reshape(oh, width)
    for dy in range(oh):
        j0 = ystart[dy]
        beta = yalpha[j0]
        src_row = rows[yindex[j0]]
        for q in range(width):
            acc[q] = beta * src_row[q]
        for j in range(j0 + 1, ystart[dy + 1]):
            beta = yalpha[j]
            src_row = rows[yindex[j]]
            for q in range(width):
                acc[q] = acc[q] + beta * src_row[q]
        for q in range(width):
            v = np.rint(acc[q])
            flat[dy, q] = 0 if v < 0 else (255 if v > 255 else np.uint8(v))


@kernel
def _horizontal_sum(columns, cn, c, xindex, xalpha, k0, k1, row):  # pragma: no cover - compiled
    """One destination column's sum for every source row: ``row[r] = sum_k src_k[r] alpha_k``
    over table entries ``k0 .. k1 - 1``, as OpenCV sums it (first product, then each next one
    added in order), two source columns per pass."""
    h = row.shape[0]
    src = columns[xindex[k0] * cn + c]
    a = xalpha[k0]
    k = k0 + 1
    if k < k1:
        s2 = columns[xindex[k] * cn + c]
        a2 = xalpha[k]
        for r in range(h):
            row[r] = np.float32(src[r]) * a + np.float32(s2[r]) * a2
        k += 1
    else:
        for r in range(h):
            row[r] = np.float32(src[r]) * a
    while k + 1 < k1:
        s1 = columns[xindex[k] * cn + c]
        a1 = xalpha[k]
        s2 = columns[xindex[k + 1] * cn + c]
        a2 = xalpha[k + 1]
        for r in range(h):
            row[r] = (row[r] + np.float32(s1[r]) * a1) + np.float32(s2[r]) * a2
        k += 2
    if k < k1:
        s1 = columns[xindex[k] * cn + c]
        a1 = xalpha[k]
        for r in range(h):
            row[r] = row[r] + np.float32(s1[r]) * a1
