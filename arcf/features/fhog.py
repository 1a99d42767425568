"""Felzenszwalb HOG ("fHOG") features, a fast exact NumPy port of Dollár's toolbox ``fhog``.

BACF, ARCF and ECO all describe image patches with the 31-channel HOG variant of Felzenszwalb et
al. (PAMI 2010, "Object Detection with Discriminatively Trained Part-Based Models") as implemented
in Piotr Dollár's Image & Video Toolbox (``fhog.m`` -> ``gradientMex``: ``gradientMag`` followed by
``gradientHist`` with ``softBin=-1, useHog=2``).  The trackers' learned filters are only comparable
with the published results if the features are numerically the same, so this module reproduces
the toolbox's arithmetic rather than, say, OpenCV's or scikit-image's HOG:

1. Per-pixel gradient by central differences (one-sided, un-halved, on the image border); for
   colour images the channel with the largest squared magnitude wins (first channel on ties).
2. Hard assignment to one of ``2 * n_orients`` orientation bins over the full circle and bilinear
   (not trilinear) spatial voting into ``cell_size`` x ``cell_size`` cells; border cells, which
   only receive 7/8 of an interior cell's weight, are rescaled by 8/7.
3. Four 2x2-block L2 normalisations per cell, truncation at ``clip``, and the projection to
   ``2n`` contrast-sensitive + ``n`` contrast-insensitive + 4 texture channels (31 for n=9; the
   toolbox's always-zero 32nd channel is dropped).

This is the tracker's hottest code path (several ~200x200 patches per frame), so everything is
vectorised over pixels *and* over a batch of same-size images:

* the orientation bin is computed exactly from sign tests and four ``|gy| / |gx| > tan(b)``
  comparisons against the bin boundaries plus a lookup table - no ``atan2`` (whose float rounding
  would move pixels lying near a boundary, e.g. exactly vertical gradients, to the wrong bin);
* the spatial voting weights only depend on the pixel's position modulo the cell size, so the
  four bilinear weight maps and the target-cell indices are precomputed per image shape (and
  cached), and the histogram is four ``np.bincount`` calls over all pixels of the batch;
* normalisation works on whole (batch, cells) arrays with one small loop over the 4 normalisers.
"""

from __future__ import annotations

from fractions import Fraction
from functools import lru_cache

import cv2
import numpy as np

__all__ = ["fhog", "fhog_num_channels"]

#: Weight of the 4 texture (gradient-energy) channels, as in the toolbox (~ 1 / sqrt(18)).
_TEXTURE_WEIGHT = np.float32(0.2357)


def fhog_num_channels(n_orients: int = 9) -> int:
    """Number of output channels: ``2n`` sensitive + ``n`` insensitive + 4 texture (31 for n=9)."""
    return 3 * n_orients + 4


def fhog(
    images: np.ndarray, cell_size: int = 4, n_orients: int = 9, clip: float = 0.2
) -> np.ndarray:
    """Felzenszwalb HOG of one image or a batch of same-size images (Dollár toolbox semantics).

    Args:
        images: pixel values in 0..255 (``uint8`` or any real dtype; computed in float32).  The
            layout is decided by ``ndim`` because a 3-D array would otherwise be ambiguous:

            * ``ndim == 2``: one grey image ``(H, W)``;
            * ``ndim == 3``: one colour image ``(H, W, C)``; the last axis must be 1 or 3 (a
              3-D array with another last axis raises, use ``(N, H, W, 1)`` for a batch of grey
              images);
            * ``ndim >= 4``: a batch ``(..., H, W, C)`` with any leading batch dimensions and any
              number of channels ``C``.

            For ``C > 1`` each pixel uses the gradient of the channel with the largest gradient
            magnitude (first channel on ties), so BGR vs RGB order does not matter.
        cell_size: side of the square HOG cells in pixels (4 for full-size patches; 1..3 are used
            for tiny targets).  Only the top-left ``(H // cell_size) * cell_size`` rows and
            ``(W // cell_size) * cell_size`` columns contribute, as in the toolbox.
        n_orients: number of contrast-insensitive orientations (9 in all the trackers).
        clip: truncation value of the normalised histogram entries (0.2).

    Returns:
        float32 array ``(..., H // cell_size, W // cell_size, 3 * n_orients + 4)`` (31 channels for
        ``n_orients=9``): channels ``0 .. 2n-1`` contrast-sensitive orientations (bin ``o`` is
        centred on gradient direction ``o * 180 / n`` degrees, measured from +x towards +y, i.e.
        downwards), ``2n .. 3n-1`` contrast-insensitive orientations (``o`` and ``o + n``
        merged), and 4 texture channels (one per block normaliser, in the toolbox's order: the
        2x2 block starting at the cell, the one a row up, a column left, and up-left).

    Notes:
        If the cell grid has a single row (or column), no 2x2 block fits; the block normalisers
        are then computed over 1x2 / 2x1 / 1x1 "blocks" made of the cells that exist (the toolbox
        reads uninitialised/unnormalised values in that case), and the 8/7 border correction is
        applied twice to that row/column, exactly as the toolbox's sequential loops do.
    """
    x = np.asarray(images)
    if x.ndim == 2:
        x = x[..., None]
        lead: tuple[int, ...] = ()
    elif x.ndim == 3:
        if x.shape[-1] not in (1, 3):
            raise ValueError(
                f"fhog: a 3-D input must be one (H, W, C) image with C in (1, 3), got shape "
                f"{x.shape}; pass a batch of grey images as (N, H, W, 1)"
            )
        lead = ()
    elif x.ndim >= 4:
        lead = x.shape[:-3]
    else:
        raise ValueError(f"fhog: expected a 2-D, 3-D or 4+-D array, got shape {x.shape}")
    if cell_size < 1 or not 1 <= n_orients <= 100:
        raise ValueError("fhog: need cell_size >= 1 and 1 <= n_orients <= 100")
    if x.dtype.kind not in "uifb":
        raise TypeError(f"fhog: unsupported dtype {x.dtype}")

    height, width, channels = x.shape[-3:]
    hb, wb = height // cell_size, width // cell_size
    n_out = fhog_num_channels(n_orients)
    if hb == 0 or wb == 0 or x.size == 0:
        return np.zeros((*lead, hb, wb, n_out), np.float32)

    n_img = int(np.prod(lead, dtype=np.int64)) if lead else 1
    x = x.reshape(n_img, height, width, channels)
    gx, gy, mag2 = _dominant_gradient(x, hb * cell_size, wb * cell_size)
    hist = _histogram(gx, gy, mag2, cell_size, n_orients)
    out = _normalise(hist, n_img, cell_size, n_orients, np.float32(clip))
    return out.reshape(*lead, hb, wb, n_out)


# --------------------------------------------------------------------------------------------
# 1. Gradients
# --------------------------------------------------------------------------------------------


def _float_planes(x: np.ndarray) -> list[np.ndarray]:
    """Split ``(N, H, W, C)`` into C contiguous float32 planes of shape ``(N * H, W)``."""
    n_img, height, width, channels = x.shape
    if channels == 1:
        return [np.ascontiguousarray(x.reshape(n_img * height, width), dtype=np.float32)]
    stacked = x.reshape(n_img * height, width, channels)
    if channels <= 4 and x.dtype in (np.uint8, np.float32, np.float64):
        planes = cv2.split(np.ascontiguousarray(stacked))  # much faster than a strided copy
    else:
        planes = list(np.moveaxis(stacked, -1, 0))
    return [np.ascontiguousarray(p, dtype=np.float32) for p in planes]


def _doubled_gradient(plane: np.ndarray, n_img: int) -> tuple[np.ndarray, np.ndarray]:
    """Toolbox derivative ``gradientMag`` uses, times two: ``(2 gx, 2 gy)`` of ``(N * H, W)``.

    Interior: ``I[i+1] - I[i-1]`` (half of it is the central difference); first/last index:
    ``2 (I[1] - I[0])`` / ``2 (I[n-1] - I[n-2])`` (the toolbox's un-halved one-sided
    difference); zero along an axis of length 1.  Doubling is exact in floating point, so bins
    and channel choices are unaffected; the factor 1/2 is folded into the voting weights.  Both
    interiors are computed as one shifted subtraction over the flattened batch, and the rows /
    columns where that straddles two rows or two images are then overwritten by the border rule.
    """
    height = plane.shape[0] // n_img
    width = plane.shape[1]
    flat = plane.reshape(-1)
    gx = np.empty_like(plane)
    gy = np.empty_like(plane)
    if width > 1:
        np.subtract(flat[2:], flat[:-2], out=gx.reshape(-1)[1:-1])
        for dst, a, b in ((0, 1, 0), (width - 1, width - 1, width - 2)):
            col = gx[:, dst]
            np.subtract(plane[:, a], plane[:, b], out=col)
            col *= 2.0
    else:
        gx.fill(0.0)
    if height > 1:
        np.subtract(flat[2 * width :], flat[: -2 * width], out=gy.reshape(-1)[width:-width])
        p3 = plane.reshape(n_img, height, width)
        g3 = gy.reshape(n_img, height, width)
        for dst, a, b in ((0, 1, 0), (height - 1, height - 1, height - 2)):
            row = g3[:, dst]
            np.subtract(p3[:, a], p3[:, b], out=row)
            row *= 2.0
    else:
        gy.fill(0.0)
    return gx, gy


def _dominant_gradient(
    x: np.ndarray, h0: int, w0: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Doubled gradient of the channel with the largest magnitude, cropped to ``(h0, w0)``.

    Returns three contiguous float32 arrays ``(N, h0, w0)``: ``2 gx``, ``2 gy`` and
    ``4 (gx^2 + gy^2)``.  Like the toolbox, a channel replaces the current best only if its
    squared magnitude is strictly larger, so the first channel wins ties.
    """
    n_img, height, width, _ = x.shape
    best_gx = best_gy = best_m2 = np.empty(0, np.float32)
    for c, plane in enumerate(_float_planes(x)):
        gx, gy = _doubled_gradient(plane, n_img)
        m2 = gx * gx
        m2 += gy * gy
        if c == 0:
            best_gx, best_gy, best_m2 = gx, gy, m2
        else:
            # Masked copies (branch-free SIMD in OpenCV; np.where/copyto are ~30x slower here).
            better = cv2.compare(m2, best_m2, cv2.CMP_GT)
            cv2.copyTo(gx, better, best_gx)
            cv2.copyTo(gy, better, best_gy)
            np.maximum(best_m2, m2, out=best_m2)
    out = []
    for a in (best_gx, best_gy, best_m2):
        a = a.reshape(n_img, height, width)
        if h0 != height or w0 != width:
            a = np.ascontiguousarray(a[:, :h0, :w0])
        out.append(a)
    return out[0], out[1], out[2]


# --------------------------------------------------------------------------------------------
# 2. Orientation binning and spatial voting
# --------------------------------------------------------------------------------------------


@lru_cache(maxsize=16)
def _orientation_tables(n_orients: int) -> tuple[tuple[float, ...], np.ndarray]:
    """Thresholds on ``|gy| / |gx|`` and the code -> contrast-sensitive-bin table.

    The toolbox bin is ``o = floor(theta * 2n / 2pi + 1/2) mod 2n`` with ``theta`` in
    ``[0, 2pi)``, i.e. the number of bin boundaries ``(k + 1/2) * 180 / n`` degrees that do not
    exceed theta.  Folding theta by the signs of gx and gy into ``theta'`` in ``[0, 90]``
    reduces this to ``q``, the number of thresholds below ``|gy| / |gx|``: one per boundary
    ``b`` in (0, 90) at ``tan(b)``.  A boundary whose tangent is rational can be hit exactly,
    and there the rounding direction depends on the quadrant, so it gets a state of its own
    (two thresholds): 45 degrees (``|gx| == |gy|``, when n = 2, 6, 10, ...) and 90 degrees
    (``gx == 0``, when n is odd; e.g. a vertical gradient goes to bin 5 = int(4.5 + 0.5) for
    n = 9, as in exact arithmetic and in the toolbox).  By Niven's theorem these are the only
    rational tangents.  The pair (quadrant, q) then determines the bin; the table is filled by
    evaluating the exact formula, in rational arithmetic, at a representative angle of every
    state, so it is correct by construction for any n.

    Returns the increasing float32 thresholds (tested with ``>``) and a 256-entry uint8 table
    indexed by ``code = q + n_q * (2 * [gy < 0] + [gx < 0])``, ``n_q = len(thresholds) + 1``.
    """
    step = Fraction(180, n_orients)  # bin width in degrees (20 for n = 9)
    f32 = np.float32
    thresholds: list[float] = []
    states: list[Fraction] = []  # representative folded angle of each q value
    lo = Fraction(0)
    k = 0
    while (b := (k + Fraction(1, 2)) * step) <= 90:
        states.append((lo + b) / 2)  # strictly between the previous boundary and b
        if b == 45:  # tan = 1: separate states for ratio < 1, == 1, > 1
            thresholds += [float(np.nextafter(f32(1), f32(0))), 1.0]
            states.append(b)
        elif b == 90:  # ratio == inf (gx == 0): "> float32 max"
            thresholds.append(float(np.finfo(f32).max))
            states.append(b)
        else:
            thresholds.append(float(f32(np.tan(np.deg2rad(float(b))))))
        lo = b
        k += 1
    if lo < 90:
        states.append((lo + 90) / 2)  # last interval, up to and including 90 degrees
    n_q = len(states)
    assert n_q == len(thresholds) + 1 and 4 * n_q <= 256

    def exact_bin(theta: Fraction) -> int:
        return int((theta / step + Fraction(1, 2)) // 1) % (2 * n_orients)

    table = np.zeros(256, np.uint8)
    for q, tp in enumerate(states):
        # Quadrant (2 * [gy < 0] + [gx < 0]) -> theta.  Zero components compare as
        # non-negative; the resulting angles 0 / 90 / 180 / 270 are all mapped correctly.
        for quad, theta in ((0, tp), (1, 180 - tp), (2, (360 - tp) % 360), (3, 180 + tp)):
            table[q + n_q * quad] = exact_bin(theta)
    table.setflags(write=False)
    return tuple(thresholds), table


def _orientation_code(gx: np.ndarray, gy: np.ndarray, n_orients: int) -> np.ndarray:
    """uint8 code of each gradient direction; ``_orientation_tables`` maps it to the bin.

    Exact (no ``atan2``): besides sign tests, only ``|gy| / |gx| > threshold`` is evaluated, in
    float32.  For every gradient an 8-bit image can produce (components k/2, |k| <= 510,
    and more generally k/4) this was checked exhaustively to agree with exact arithmetic: the
    closest such direction is ~5e-7 (relative) away from a boundary, 8x the float32 rounding.
    """
    thresholds, _ = _orientation_tables(n_orients)
    n_q = len(thresholds) + 1
    code = np.less(gy, 0).view(np.uint8)
    code += code
    code += np.less(gx, 0)
    code *= np.uint8(n_q)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.divide(gy, gx)  # inf for vertical gradients, nan for zero gradients
    np.abs(ratio, out=ratio)
    for t in thresholds:
        code += ratio > np.float32(t)
    return code


def _orientation_bins(gx: np.ndarray, gy: np.ndarray, n_orients: int = 9) -> np.ndarray:
    """Contrast-sensitive bin (uint8, ``0 .. 2n-1``) of every gradient direction (gx, gy).

    Equals ``int(theta * 2n / 2pi + 0.5) mod 2n`` with ``theta = atan2(gy, gx)`` in
    ``[0, 2pi)``, evaluated exactly (used by the histogram via a table; handy for tests).
    """
    _, table = _orientation_tables(n_orients)
    return table[_orientation_code(gx, gy, n_orients)]


@lru_cache(maxsize=16)
def _voting_layout(
    n_img: int, hb: int, wb: int, cell: int
) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Target-cell index and the 4 bilinear weight maps of every pixel of the (h0, w0) crop.

    For pixel column ``x``: ``xb = (x + 0.5) / cell - 0.5``; it votes ``1 - xd`` into cell
    column ``floor(xb)`` and ``xd = xb - floor(xb)`` into the next one (same for rows); the
    four products weight the four target cells.  The returned flat index addresses the first
    (upper-left) target cell in one orientation plane of a histogram padded by one cell on the
    top/left, shape ``(n_img, hb + 1, wb + 1)``.  The weights include the toolbox's
    ``1 / cell^2`` and the 1/2 undoing the doubled gradients.  Both depend only on the position
    modulo ``cell`` and the shape, hence the cache.
    """
    pos = (np.arange(cell) + 0.5) / cell - 0.5
    first = np.floor(pos)  # -1 or 0: offset of the first target cell
    frac = pos - first
    h0, w0 = hb * cell, wb * cell
    # Padded index (0 .. hb / 0 .. wb) of the first target row / column of each pixel.
    row0 = (np.arange(hb).repeat(cell) + np.tile(first, hb) + 1).astype(np.intp)
    col0 = (np.arange(wb).repeat(cell) + np.tile(first, wb) + 1).astype(np.intp)
    base = (row0[:, None] * (wb + 1) + col0[None, :]).reshape(-1)
    img_off = np.arange(n_img, dtype=np.intp) * ((hb + 1) * (wb + 1))
    index = (img_off[:, None] + base[None, :]).reshape(-1)
    index.setflags(write=False)

    wy = np.tile(np.stack([1.0 - frac, frac]), (1, hb))  # (2, h0)
    wx = np.tile(np.stack([1.0 - frac, frac]), (1, wb))  # (2, w0)
    scale = 0.5 / (cell * cell)
    weights = []
    for a in range(2):
        for b in range(2):
            w = (scale * wy[a][:, None] * wx[b][None, :]).reshape(1, h0 * w0)
            w.setflags(write=False)
            weights.append(w)
    return index, tuple(weights)


def _histogram(
    gx: np.ndarray, gy: np.ndarray, mag2: np.ndarray, cell: int, n_orients: int
) -> np.ndarray:
    """Toolbox ``gradHist`` (hard orientation, bilinear spatial): float32 ``(2n, N, hb, wb)``.

    Orientation-major ("planar") so that the normalisation can broadcast over whole planes.
    """
    n_img, h0, w0 = gx.shape
    hb, wb = h0 // cell, w0 // cell
    n_bins = 2 * n_orients
    index, weights = _voting_layout(n_img, hb, wb, cell)
    plane = n_img * (hb + 1) * (wb + 1)
    _, table = _orientation_tables(n_orients)
    offsets = table.astype(np.int32) * np.int32(plane)  # bin -> start of its plane
    code = _orientation_code(gx, gy, n_orients).reshape(n_img * h0, w0)
    key = index + cv2.LUT(code, offsets).reshape(-1)
    mag = np.sqrt(mag2).astype(np.float64).reshape(n_img, h0 * w0)  # 2 * M
    shape = (n_bins, n_img, hb + 1, wb + 1)
    hist = np.zeros((n_bins, n_img, hb, wb), np.float64)
    for (a, b), w in zip(((0, 0), (0, 1), (1, 0), (1, 1)), weights, strict=True):
        votes = np.bincount(key, (mag * w).reshape(-1), minlength=n_bins * plane)
        votes = votes.reshape(shape)
        # Shift the votes for the (a, b)-th neighbour of the first target cell and drop the
        # padding (cells -1 and hb / wb, which the toolbox discards as well).
        hist += votes[:, :, 1 - a : hb + 1 - a, 1 - b : wb + 1 - b]
    hist = hist.astype(np.float32)
    # Border cells only collect 7/8 of an interior cell's weight: rescale them, sequentially
    # like the toolbox, so a single row / column gets the factor twice.
    s = np.float32(8.0 / 7.0)
    hist[:, :, 0] *= s
    hist[:, :, -1] *= s
    hist[:, :, :, 0] *= s
    hist[:, :, :, -1] *= s
    return hist


# --------------------------------------------------------------------------------------------
# 3. Block normalisation and the output channels
# --------------------------------------------------------------------------------------------


def _normalise(
    r1: np.ndarray, n_img: int, cell: int, n_orients: int, clip: np.float32
) -> np.ndarray:
    """Toolbox ``hogNormMatrix`` + ``hogChannels``: ``(2n, N, hb, wb)`` -> ``(N, hb, wb, 3n+4)``."""
    n_bins, _, hb, wb = r1.shape
    n = n_orients
    cells = n_img * hb * wb
    # R = [R1; R2] with R2 the contrast-insensitive histogram (o and o + n merged).
    r = np.empty((3 * n, cells), np.float32)
    r[:n_bins] = r1.reshape(n_bins, cells)
    np.add(r[:n], r[n:n_bins], out=r[n_bins:])
    r2 = r[n_bins:]
    energy = np.einsum("kp,kp->p", r2, r2).reshape(n_img, hb, wb)

    # Sums over 2x2 blocks of cells (1-wide "blocks" if there is a single row / column).
    if hb > 1:
        energy = energy[:, :-1] + energy[:, 1:]
    if wb > 1:
        energy = energy[:, :, :-1] + energy[:, :, 1:]
    eps = np.float32(1e-4) / 4 / cell / cell / cell / cell
    block = np.float32(1.0) / np.sqrt(energy + eps)
    # Edge-pad by one cell on every side -> (N, hb + 1, wb + 1).
    ri = np.clip(np.arange(hb + 1) - 1, 0, block.shape[1] - 1)
    ci = np.clip(np.arange(wb + 1) - 1, 0, block.shape[2] - 1)
    norm = block[:, ri][:, :, ci]
    normalisers = (
        norm[:, 1:, 1:],  # the block whose top-left cell is this cell
        norm[:, :-1, 1:],  # the block one row up
        norm[:, 1:, :-1],  # one column left
        norm[:, :-1, :-1],  # up-left
    )

    out = np.empty((3 * n + 4, cells), np.float32)
    acc = out[: 3 * n]
    tmp = np.empty_like(r)
    for k, nk in enumerate(normalisers):
        np.multiply(r, np.ascontiguousarray(nk).reshape(1, cells), out=tmp)
        np.minimum(tmp, clip, out=tmp)
        if k == 0:
            acc[...] = tmp
        else:
            acc += tmp
        np.sum(tmp[:n_bins], axis=0, out=out[3 * n + k])
    acc *= np.float32(0.5)
    out[3 * n :] *= _TEXTURE_WEIGHT
    return cv2.transpose(out)
