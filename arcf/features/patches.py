"""Image patches around the target, padded by replicating the border as the release does.

Positions are (row, col) in 1-based pixel coordinates (the datasets' and MATLAB's frame), so the
release's rounding rules carry over unchanged; conversion to array indices happens here only.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .resize import resample_area_windows, resize_area, resize_area_windows


def matlab_round(v: float) -> int:
    """MATLAB's ``round``: halves away from zero (Python's ``round`` goes to even)."""
    return math.floor(v + 0.5) if v >= 0 else -math.floor(-v + 0.5)


def as_rgb(patches: np.ndarray) -> np.ndarray:
    """``(..., H, W, C)`` uint8 windows cut from a BGR frame, in the release's RGB order.

    The trackers keep frames in OpenCV's BGR and convert only the windows they cut: the same
    pixels as converting the frame first, since every sampler treats channels alike, for a few
    hundred kilobytes instead of the whole frame. Grey (C = 1) passes through.
    """
    if patches.shape[-1] != 3:
        return patches
    flat = np.ascontiguousarray(patches).reshape(-1, patches.shape[-2], 3)
    return cv2.cvtColor(flat, cv2.COLOR_BGR2RGB).reshape(patches.shape)


def resize_auto(patch: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """The release's ``mexResize(patch, out_hw, 'auto')``: bilinear or area interpolation.

    The rule is the release's, not "shrink means area": linear interpolation when the requested
    number of *columns* exceeds the patch's number of *rows*, area otherwise. On the square
    windows of the translation filters both rules agree; on the DSST scale filter's non-square
    samples (e.g. a 48x22 window resized to 32x15) they do not, and which one is used decides
    whether ARCF-HC's boxes match the release's on truck4_1 after frame 34 (docs/release.md,
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


def _halving_runs(start: int, size: int, n: int) -> tuple[int, int, int]:
    """Along one axis of a replicated window of ``size`` (even) pixels starting at ``start``
    in an image of ``n`` pixels: how many 2-pixel blocks before, inside and after the image.

    A block is inside when both its pixels are distinct image pixels; every other block reads
    one edge pixel twice (a block straddling the edge reads the edge and its replica)."""
    blocks = size // 2
    first = min(max(-(start // 2), 0), blocks)  # ceil(-start / 2), clamped
    last = min(max((n - start) // 2, first), blocks)  # blocks ending at or before pixel n
    return first, last - first, blocks - last


def halve_replicated(image: np.ndarray, top: int, left: int, h: int, w: int) -> np.ndarray:
    """``cv2.resize(crop_replicate(image, top, left, h, w), (w // 2, h // 2), INTER_AREA)``
    for even ``h`` and ``w``, bit for bit, without copying the window first.

    Why: ARCF-H's windows around a large target are ~1100 px, taller than a 720-px frame, and
    replicating the border into a 3.6 MB copy (``copyMakeBorder``) cost as much as halving it
    (0.35 ms, twice a frame). Each 2x2 block that reads an edge pixel twice (outside the image
    or straddling its edge) is a block of a 2-pixel strip of that edge pixel, so the halving is
    OpenCV's on the image inside, and on thin strips of edge pixels for the rest, repeated.
    """
    ih, iw = image.shape[:2]
    rb, rn, ra = _halving_runs(top, h, ih)
    cb, cn, ca = _halving_runs(left, w, iw)
    if rn == 0 or cn == 0 or not (rb or ra or cb or ca):  # nothing inside, or all inside
        out = cv2.resize(crop_replicate(image, top, left, h, w), (w // 2, h // 2),
                         interpolation=cv2.INTER_AREA)
        return out[..., None] if out.ndim < image.ndim else out
    r0, c0 = top + 2 * rb, left + 2 * cb  # the first image pixel of the inside blocks
    # Source rows / columns of a compact window: one edge block before, the inside blocks,
    # one edge block after (each only where the window has such blocks).
    rows = np.concatenate([[0, 0] if rb else [], np.arange(r0, r0 + 2 * rn),
                           [ih - 1, ih - 1] if ra else []]).astype(np.intp)
    cols = np.concatenate([[0, 0] if cb else [], np.arange(c0, c0 + 2 * cn),
                           [iw - 1, iw - 1] if ca else []]).astype(np.intp)
    out = np.empty((h // 2, w // 2, image.shape[2]), np.uint8)

    def halve(src: np.ndarray) -> np.ndarray:
        half = cv2.resize(src, (src.shape[1] // 2, src.shape[0] // 2),
                          interpolation=cv2.INTER_AREA)
        return half.reshape(src.shape[0] // 2, src.shape[1] // 2, image.shape[2])

    # the inside, straight from the image (a view)
    out[rb: rb + rn, cb: cb + cn] = halve(image[r0: r0 + 2 * rn, c0: c0 + 2 * cn])
    top_row = 1 if rb else 0
    if rb or ra:  # edge rows: one halved 2-row strip each, repeated
        for count, at, pick in ((rb, 0, 0), (ra, rb + rn, len(rows) - 2)):
            if count:
                strip = halve(image[np.ix_(rows[pick: pick + 2], cols)])  # (1, cb'+cn+ca', C)
                out[at: at + count] = _expand_columns(strip[0], cb, cn, ca)
    if cb or ca:  # edge columns of the inside rows
        inside_rows = rows[2 * top_row: 2 * top_row + 2 * rn]
        for count, at, pick in ((cb, 0, 0), (ca, cb + cn, len(cols) - 2)):
            if count:
                strip = halve(image[np.ix_(inside_rows, cols[pick: pick + 2])])  # (rn, 1, C)
                out[rb: rb + rn, at: at + count] = strip
    return out


def _expand_columns(row: np.ndarray, before: int, inside: int, after: int) -> np.ndarray:
    """A compact halved row (an edge block, the inside blocks, an edge block) at full width."""
    first = 1 if before else 0
    parts = []
    if before:
        parts.append(np.repeat(row[:1], before, axis=0))
    parts.append(row[first: first + inside])
    if after:
        parts.append(np.repeat(row[-1:], after, axis=0))
    return np.concatenate(parts)


def bacf_patch(
    image: np.ndarray, pos: tuple[float, float], size: tuple[int, int], out_hw: tuple[int, int]
) -> np.ndarray:
    """BACF's ``get_pixels``: a ``size`` window around ``pos`` resized to ``out_hw``.

    Both trackers of the release sample this way (ARCF-HC too, although it is built on ECO's
    code: it does not use ECO's ``sample_patch`` with its integer pre-decimation, whose windows
    differ by up to 156 grey levels on boat1; docs/release.md, detail 6).

    1-based rows ``floor(pos) + (1..s) - floor(s/2)``, so the array index of the first row is
    ``floor(pos) - floor(s/2)``.
    """
    ((top, left, sh, sw),) = _placed(pos, [size])
    return resize_auto(crop_replicate(image, top, left, sh, sw), out_hw)


def _placed(
    pos: tuple[float, float], sizes: list[tuple[int, int]]
) -> list[tuple[int, int, int, int]]:
    """``(top, left, h, w)`` array indices of each window by the release's rule (a side below
    one pixel becomes 2, as in ``get_pixels``)."""
    fr, fc = math.floor(pos[0]), math.floor(pos[1])
    boxes = []
    for h, w in sizes:
        h, w = (h if h >= 1 else 2), (w if w >= 1 else 2)
        boxes.append((fr - h // 2, fc - w // 2, h, w))
    return boxes


def _cover(boxes: list[tuple[int, int, int, int]]) -> tuple[int, int, int, int]:
    """``(top, left, bottom, right)`` of the region covering all ``boxes``."""
    return (min(b[0] for b in boxes), min(b[1] for b in boxes),
            max(b[0] + b[2] for b in boxes), max(b[1] + b[3] for b in boxes))


def release_windows(
    image: np.ndarray,
    pos: tuple[float, float],
    sizes: list[tuple[int, int]],
    out_hw: tuple[int, int],
) -> np.ndarray:
    """``bacf_patch`` of each ``(h, w)`` size around ``pos``, stacked: ``(N, oh, ow, C)``.

    Bit for bit the release's sampler, window by window; the area shrinks share one
    transposition of the image part they read, and none copies a replicated border
    (``resize_area_windows``).
    """
    boxes = _placed(pos, sizes)
    oh, ow = out_hw
    # mexResize's rule (resize_auto): area unless the new width exceeds the window's height
    area = [i for i, (_, _, h, _) in enumerate(boxes) if ow <= h]
    out = np.empty((len(sizes), oh, ow, image.shape[2]), np.uint8)
    if area:
        out[area] = resize_area_windows(image, [boxes[i] for i in area], out_hw)
    for i, (t, c, h, w) in enumerate(boxes):
        if ow > h:
            out[i] = resize_auto(crop_replicate(image, t, c, h, w), out_hw)
    return out


def pyramid_windows(
    image: np.ndarray,
    pos: tuple[float, float],
    sizes: list[tuple[int, int]],
    out_hw: tuple[int, int],
) -> np.ndarray:
    """Windows of the given ``(h, w)`` sizes around ``pos``, each resampled to ``out_hw``, fast.

    The preset option ``sampling="pyramid"``: an approximation of the release's sampler
    (``bacf_patch``, one area resize per window) for windows much larger than the output. The
    region covering all windows is cut once and halved with exact 2x2 box averages (OpenCV's
    SIMD integer area path) into a small pyramid; each window is then read from the level whose
    remaining shrink is below 2, by area (box) weights at the window's exact, fractional
    position and size there (``resample_area``). Windows are placed by the release's rule
    (first row ``floor(pos) - floor(h / 2)``); a window less than twice the output in either
    direction is sampled exactly as ``bacf_patch`` does. Returns ``(N, oh, ow, C)`` uint8.

    Why: ARCF-H shrinks five nearly equal ~1100-px windows per frame on a large target, and
    the DSST scale filter of ARCF-HC 33 windows twice a frame; one shared halving pyramid
    reads each source pixel once instead of once per window (docs/results-speed.md measures
    the speed and the accuracy against the exact sampler).
    """
    oh, ow = out_hw
    boxes = _placed(pos, sizes)
    levels = [max(0, math.floor(math.log2(min(h / oh, w / ow)))) for _, _, h, w in boxes]
    out = np.empty((len(sizes), oh, ow, image.shape[2]), np.uint8)
    deepest = max(levels)
    pyramid: list[np.ndarray] = []
    if deepest > 0:
        top, left, bottom, right = _cover([b for b, k in zip(boxes, levels, strict=True) if k])
        step = 1 << deepest
        height = -(-(bottom - top) // step) * step  # whole 2^k blocks: extended down / right
        width = -(-(right - left) // step) * step
        level = halve_replicated(image, top, left, height, width)
        pyramid.append(level)
        for _ in range(deepest - 1):
            h, w = level.shape[:2]
            level = cv2.resize(level, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
            if level.ndim < image.ndim:
                level = level[..., None]
            pyramid.append(level)
    exact = [i for i, k in enumerate(levels) if k == 0]
    if exact:  # cut as the release does, sharing one crop and one transposition
        out[exact] = release_windows(image, pos, [sizes[i] for i in exact], out_hw)
    for k in range(1, deepest + 1):
        at_k = [i for i, level in enumerate(levels) if level == k]
        if not at_k:
            continue
        scale = 1 << k
        out[at_k] = resample_area_windows(
            pyramid[k - 1],
            [(((boxes[i][0] - top) / scale, (boxes[i][1] - left) / scale),
              (boxes[i][2] / scale, boxes[i][3] / scale)) for i in at_k],
            out_hw,
        )
    return out
