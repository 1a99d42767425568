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

* the orientation bin is computed exactly from sign tests and a few ``|gy| / |gx| > tan(b)``
  comparisons against the bin boundaries plus a lookup table - no ``atan2`` (whose rounding
  can move pixels lying on or near a boundary, e.g. exactly vertical gradients, to the wrong
  bin; ``cv2.phase`` misbins ~0.01% of all 8-bit gradients);
* the spatial voting weights only depend on the pixel's position modulo the cell size, so the
  bilinear weight maps and target-cell indices are precomputed per image shape (and cached);
  the two horizontal neighbours travel together as the real and imaginary part of a complex64
  vote, so the whole histogram is two ``np.add.at`` scatters over all pixels of the batch;
* normalisation works on whole orientation planes with one small loop over the 4 normalisers;
* large intermediates live in per-thread scratch buffers that are reused across calls: fresh
  multi-100-kB temporaries page-fault on every call, which costs more than the arithmetic;
  a batch is processed in chunks whose intermediates fit in the L2 cache.

Cell size 1 (tiny targets) skips spatial interpolation altogether, as the toolbox does.

``arithmetic="release"`` swaps step 1's exact magnitude and step 2's exact orientation for the
toolbox's SSE approximations (approximate reciprocal square root, acos lookup table), which is
what the authors' ARCF release computed; see ``fhog``.
"""

from __future__ import annotations

import math
import threading
from fractions import Fraction
from functools import lru_cache
from typing import Literal

import cv2
import numpy as np

from .._jit import fma32, kernel
from .sse import SSETables

__all__ = ["Arithmetic", "ArithmeticMode", "fhog", "fhog_num_channels"]

#: ``fhog``'s arithmetic: exact gradient magnitude and orientation, or the authors' release's
#: approximations (SSE reciprocal square root, acos lookup table) with the SSE instructions
#: either modelled (``"release"``) or replayed from a CPU's measured tables (``SSETables``).
ArithmeticMode = Literal["exact", "release"]
Arithmetic = ArithmeticMode | SSETables

#: Weight of the 4 texture (gradient-energy) channels, as in the toolbox (~ 1 / sqrt(18)).
_TEXTURE_WEIGHT = np.float32(0.2357)

#: The modelled release arithmetic runs as one fused kernel (``_release_histogram``); the
#: separate steps remain for the replayed SSE tables and for tests that swap the instructions.
_FUSED_RELEASE = True

#: Working-set budget per chunk of a batch (bytes), sized for a 2-4 MB L2 cache; see
#: ``_chunk_size``.
_CHUNK_BYTES = 3 << 20

_NO_WINDOW = np.zeros((0, 0), np.float32)  # ``fhog(window=None)``


def fhog_num_channels(n_orients: int = 9) -> int:
    """Number of output channels: ``2n`` sensitive + ``n`` insensitive + 4 texture (31 for n=9)."""
    return 3 * n_orients + 4


def fhog(
    images: np.ndarray,
    cell_size: int = 4,
    n_orients: int = 9,
    clip: float = 0.2,
    arithmetic: Arithmetic = "exact",
    out: np.ndarray | None = None,
    window: np.ndarray | None = None,
    bgr: bool = False,
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
        arithmetic: ``"exact"`` (default): exact gradient magnitude ``sqrt(gx^2 + gy^2)`` and
            exact orientation bins.  ``"release"``: the arithmetic of the toolbox's SSE code as
            the authors' ARCF release ran it (``gradMag``): ``_m = min(rsqrt(m2), 1e10)``,
            magnitude ``M = rcp(_m)`` (so a zero gradient votes ``~1e-10``), orientation
            ``acos`` read from the toolbox's 20020-entry float32 table at the truncated index
            ``(int)(gx * _m * 10000)`` (sign flipped where gy's sign bit is set, ``+ PI`` where
            ``gy < 0``), binned in float32 by ``gradQuantize``.  On uint8 images every
            possible pixel's bin and magnitude are tabulated once with this arithmetic, which
            makes it faster than exact mode (5 real 200x200x3 patches: 2.2 ms vs 3.0 ms, one
            core).

            SSE's ``rsqrt`` / ``rcp`` are ~12-bit approximations whose last bits differ
            between CPU vendors (the release was traced on an AMD EPYC), so they are modelled:
            ``rsqrt(x)`` = ``1 / sqrt(x)`` rounded to nearest with 13 significant bits (AMD's
            results carry 12 fraction bits, e.g. ``rsqrt(256) = 0x3d7ff800``), ``rcp`` =
            correctly rounded float32 ``1 / x``.  Chosen by measurement against all 28 traced
            patches of the release (``reference_release/traces``; 1.68 M values); values
            differing by > 1e-3 (max abs difference): this model 33 in 3 patches (0.044);
            correctly rounded rsqrt 269 in 3 (0.19); this machine's Intel ``rsqrtps`` 1670 in
            22 (0.24); a 12-bit table model 2466 in 23 (0.24); exact arithmetic 251 in 9
            (0.099).  The remaining 33 are pixels landing in a neighbouring orientation bin;
            elsewhere the residual is < 1.1e-4 (mean 2.5e-6), the release's magnitude error.
            Only RGB channel order reproduces the release (it reads images as RGB; BGR changes
            ~15 % of all values by > 1e-3, max 0.4, because of the tie rule above).

            An :class:`~arcf.features.sse.SSETables`: the release arithmetic with a CPU's own
            ``RSQRTPS`` / ``RCPPS`` replayed bit for bit from the tables that
            ``tools/sse_approx_dump.c`` measured on it, instead of the model.
        out: where to write the result, a float32 array of the result's shape with any strides
            (e.g. a transposed view of a channel-first buffer, which is how the trackers get
            their feature maps without a copy); returned.
        window: a float32 ``(H // cell_size, W // cell_size)`` map that multiplies every
            channel as it is written (the trackers' cosine window): the same float32 product
            as ``features * window`` afterwards, without another pass over the maps.
        bgr: the colour images' channels are in OpenCV's BGR order: they are read as RGB
            (which decides the first-channel tie rule above), without converting them first.

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

        Thread-safe.  Each calling thread keeps a few MB of scratch buffers alive between calls
        (sized by the largest chunk it has processed), which is what makes repeated calls fast.
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
    tables = arithmetic if isinstance(arithmetic, SSETables) else None
    if tables is None and arithmetic not in ("exact", "release"):
        raise ValueError(
            f"fhog: arithmetic must be 'exact', 'release' or SSETables, got {arithmetic!r}"
        )
    release = arithmetic != "exact"

    height, width, channels = x.shape[-3:]
    hb, wb = height // cell_size, width // cell_size
    n_out = fhog_num_channels(n_orients)
    shape = (*lead, hb, wb, n_out)
    if out is None:
        out = np.empty(shape, np.float32)
    elif out.shape != shape or out.dtype != np.float32:
        raise ValueError(f"fhog: out must be float32 {shape}, got {out.dtype} {out.shape}")
    if window is None:
        window = _NO_WINDOW
    elif window.shape != (hb, wb) or window.dtype != np.float32:
        raise ValueError(f"fhog: window must be float32 {(hb, wb)}, got {window.dtype} "
                         f"{window.shape}")
    if hb == 0 or wb == 0 or x.size == 0:
        out.fill(0.0)
        return out

    n_img = math.prod(lead)
    x = x.reshape(n_img, height, width, channels)
    fused = arithmetic == "release" and cell_size > 1 and _FUSED_RELEASE
    # the tabulated kernel reads BGR pixels in RGB order itself; elsewhere a reversed view
    reverse = bgr and channels == 3
    if reverse and not (fused and x.dtype == np.uint8):
        x, reverse = x[..., ::-1], False
    result = out
    out = out.view()
    try:
        out.shape = (n_img, hb, wb, n_out)  # in place: raises where only a copy could do
    except AttributeError:
        out = np.empty((n_img, hb, wb, n_out), np.float32)
    step = _chunk_size(height, width, hb, wb, n_orients)
    if fused and x.dtype == np.uint8:  # the trackers' case: one compiled call
        _release_fhog_uint8(x, step, cell_size, n_orients, clip, window, reverse, out)
    else:
        for i in range(0, n_img, step):
            chunk = x[i : i + step]
            n_chunk = chunk.shape[0]
            # R1 and (filled later) R2, orientation-major: (3n, N * hb * wb).
            r = _scratch("r", (3 * n_orients, n_chunk * hb * wb), np.float32)
            r1 = r[: 2 * n_orients].reshape(2 * n_orients, n_chunk, hb, wb)
            if fused:
                _release_histogram(chunk, cell_size, n_orients, out=r1, reverse=reverse)
            else:
                gx, gy, mag2 = _dominant_gradient(chunk, hb * cell_size, wb * cell_size)
                _histogram(gx, gy, mag2, cell_size, n_orients, out=r1, release=release,
                           tables=tables)
            _normalise(r, n_chunk, hb, wb, cell_size, n_orients, clip, window,
                       out=out[i : i + n_chunk])
    if not np.shares_memory(out, result):
        result[...] = out.reshape(shape)
    return result


def _chunk_size(height: int, width: int, hb: int, wb: int, n_orients: int) -> int:
    """Images per chunk: the batch is vectorised, but in chunks whose intermediates fit in L2.

    Why: a batch of five 200x200 patches in one go was ~1.5x slower per patch than one at a
    time, and 33 tiny patches at cell size 1 ~2x slower, because the intermediates (~64 B per
    pixel, ~(16 (3n + 4) + 16 n) B per cell) then spill to L3 / RAM.
    """
    per_image = 64 * height * width + (16 * (3 * n_orients + 4) + 16 * n_orients) * hb * wb
    return max(1, _CHUNK_BYTES // per_image)


# --------------------------------------------------------------------------------------------
# Scratch memory
# --------------------------------------------------------------------------------------------

_SCRATCH = threading.local()
_SCRATCH_MAX_BYTES = 64 << 20  # larger requests (huge images) are plain allocations


def _scratch(name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """Uninitialised work array, reused across calls (per thread, one buffer per ``name``).

    Why: on the tracker's patch sizes every intermediate is 100 kB - 2 MB, above glibc's mmap
    threshold, and a fresh one page-faults on first touch on every call; measured, that cost
    more than the arithmetic (e.g. ``cv2.split`` of 5 patches: 0.75 ms into fresh arrays vs
    0.04 ms into reused ones).  Buffers only grow, so memory is bounded by the largest batch
    seen.  Callers must not let two live arrays share a name, nor return a scratch array.
    """
    pool = _SCRATCH.__dict__  # this thread's dict
    key = (name, shape, dtype)
    arr = pool.get(key)
    if arr is not None:
        return arr
    dt = np.dtype(dtype)
    nbytes = math.prod(shape) * dt.itemsize
    if nbytes > _SCRATCH_MAX_BYTES:
        return np.empty(shape, dt)
    base = pool.get(name)
    if base is None or base.nbytes < nbytes:
        # Grow; forget the views of the old buffer so that it can be freed.
        for k in [k for k in pool if isinstance(k, tuple) and k[0] == name]:
            del pool[k]
        base = pool[name] = np.empty(max(nbytes, 64), np.uint8)
    if len(pool) > 512:  # many different shapes: start over rather than grow without bound
        pool.clear()
        pool[name] = base
    arr = pool[key] = base[:nbytes].view(dt).reshape(shape)
    return arr


# --------------------------------------------------------------------------------------------
# 1. Gradients
# --------------------------------------------------------------------------------------------


def _dominant_gradient(
    x: np.ndarray, h0: int, w0: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Doubled gradient of the channel with the largest magnitude, cropped to ``(h0, w0)``.

    Returns three contiguous float32 scratch arrays ``(N, h0, w0)``: ``2 gx``, ``2 gy`` and
    ``4 (gx^2 + gy^2)`` (see ``_gradient_kernel``).
    """
    n_img = x.shape[0]
    gx, gy, m2 = (_scratch(name, (n_img, h0, w0), np.float32) for name in ("gx", "gy", "m2"))
    _gradient_kernel(np.ascontiguousarray(x), gx, gy, m2)
    return gx, gy, m2


@kernel
def _gradient_kernel(x, gx, gy, m2):  # pragma: no cover - compiled
    """The toolbox's per-pixel gradient, doubled, of the channel with the largest magnitude.

    Pixels are converted to float32 first. Interior: ``I[i+1] - I[i-1]`` (twice the central
    difference); first / last index: ``2 (I[1] - I[0])`` / ``2 (I[n-1] - I[n-2])`` (the
    toolbox's un-halved one-sided difference); zero along an axis of length 1. Doubling is
    exact, so bins and channel choices are unaffected; the 1/2 is folded into the voting
    weights. Operands are subtracted in the toolbox's order, so even the sign of a zero
    difference is the toolbox's (``x - x = +0``; the release arithmetic reads gy's sign bit).
    ``m2 = fma(gy, gy, gx gx)`` as OpenCV's ``accumulateSquare`` (the earlier implementation)
    computed it; a channel replaces the current best only if its ``m2`` is strictly larger,
    so the first channel wins ties, as in the toolbox. ``x`` is ``(N, H, W, C)``; the outputs
    ``(N, h0, w0)`` are the top-left crop (the gradient itself uses the whole image).
    """
    n_img, height, width, channels = x.shape
    h0 = gx.shape[1]
    planes = np.empty((channels, height, width), np.float32)
    work = np.empty((3, gx.shape[2]), np.float32)
    for i in range(n_img):
        _channel_planes(x, i, False, planes)
        for r in range(h0):
            _gradient_row(planes, r, work, gx[i, r], gy[i, r], m2[i, r])


@kernel
def _channel_planes(x, i, reverse, planes):  # pragma: no cover - compiled
    """Image ``i`` of ``x`` (N, H, W, C) uint8 as channel planes ``(C, H, W)`` of ``planes``'
    dtype (float32 for the per-pixel path, uint8 for the tabulated one), so that the gradient
    reads contiguous rows, each pixel converted once; with ``reverse``, a colour image's
    channels last to first (BGR pixels as RGB planes)."""
    _, height, width, channels = x.shape
    flat = x[i].reshape(height * width * channels)
    out = planes.reshape(channels, height * width)
    first, last = (2, 0) if reverse else (0, 2)
    if channels == 3:  # written out, the de-interleaving vectorises (8x faster, measured)
        for p in range(height * width):
            out[first, p] = flat[3 * p]
            out[1, p] = flat[3 * p + 1]
            out[last, p] = flat[3 * p + 2]
    else:
        for c in range(channels):
            for p in range(height * width):
                out[c, p] = flat[channels * p + c]


@kernel
def _gradient_row(planes, r, work, gx, gy, m2):  # pragma: no cover - compiled
    """Row ``r`` of ``_gradient_kernel`` from float32 planes ``(C, H, W)`` into ``gx``, ``gy``,
    ``m2`` (w0 each); ``work`` (3, w0) float32 is scratch."""
    channels, height, width = planes.shape
    w0 = gx.shape[0]
    two = np.float32(2.0)
    dx, dy, mag = work[0], work[1], work[2]
    # the rows the vertical difference reads: (down - up), doubled at the borders
    r_up, r_down = max(r - 1, 0), min(r + 1, height - 1)
    border_row = height > 1 and (r == 0 or r == height - 1)
    for c in range(channels):
        u, m, d = planes[c, r_up], planes[c, r], planes[c, r_down]
        for col in range(w0):
            dy[col] = d[col] - u[col]
        if height == 1:
            dy[:] = 0.0
        elif border_row:
            for col in range(w0):
                dy[col] = dy[col] * two
        if width == 1:
            dx[:] = 0.0
        else:
            for col in range(1, min(w0, width - 1)):
                dx[col] = m[col + 1] - m[col - 1]
            dx[0] = (m[1] - m[0]) * two
            if w0 == width:
                dx[width - 1] = (m[width - 1] - m[width - 2]) * two
        for col in range(w0):
            mag[col] = fma32(dy[col], dy[col], dx[col] * dx[col])
        if c == 0:
            for col in range(w0):
                gx[col] = dx[col]
                gy[col] = dy[col]
                m2[col] = mag[col]
        else:
            for col in range(w0):
                if mag[col] > m2[col]:
                    gx[col] = dx[col]
                    gy[col] = dy[col]
                    m2[col] = mag[col]


@kernel
def _gradient_index_row(planes, r, dx, dy, best, index):  # pragma: no cover - compiled
    """Row ``r`` of ``_gradient_row`` on uint8 planes, in int32, as the index of the pixel's
    doubled gradient in ``_release_pixel_tables``: ``(gy + 510) * 1021 + gx + 510``.

    The same values as the float32 path (integers below 2^24 are exact in float32, so its
    differences, doublings, ``fma`` and comparisons are exact too) and the same channel choice
    (strictly larger ``m2`` wins). ``dx``, ``dy``, ``best`` (w0 int32 each) are scratch,
    separate arrays so that LLVM knows they do not overlap and vectorises (rows of one 2-D
    scratch array ran at half the speed).
    """
    channels, height, width = planes.shape
    w0 = index.shape[0]
    r_up, r_down = max(r - 1, 0), min(r + 1, height - 1)
    shift = 1 if height > 1 and (r == 0 or r == height - 1) else 0  # doubled on the border
    span, centre = _GRADIENT_SPAN, _MAX_GRADIENT * (_GRADIENT_SPAN + 1)
    for c in range(channels):
        u, m, d = planes[c, r_up], planes[c, r], planes[c, r_down]
        for col in range(w0):
            dy[col] = (np.int32(d[col]) - np.int32(u[col])) << shift
        if width == 1:
            dx[:] = 0
        else:
            for col in range(1, min(w0, width - 1)):
                dx[col] = np.int32(m[col + 1]) - np.int32(m[col - 1])
            dx[0] = (np.int32(m[1]) - np.int32(m[0])) * 2
            if w0 == width:
                dx[width - 1] = (np.int32(m[width - 1]) - np.int32(m[width - 2])) * 2
        if c == 0:
            for col in range(w0):
                best[col] = dx[col] * dx[col] + dy[col] * dy[col]
                index[col] = dy[col] * span + dx[col] + centre
        else:
            for col in range(w0):
                m2 = dx[col] * dx[col] + dy[col] * dy[col]
                better = m2 > best[col]
                best[col] = m2 if better else best[col]
                index[col] = dy[col] * span + dx[col] + centre if better else index[col]


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


def _orientation_code(
    gx: np.ndarray, gy: np.ndarray, n_orients: int, out: np.ndarray | None = None
) -> np.ndarray:
    """uint8 code of each gradient direction; ``_orientation_tables`` maps it to the bin.

    Exact (no ``atan2``): besides sign tests, only ``|gy| / |gx| > threshold`` is evaluated, in
    float32.  For every gradient an 8-bit image can produce this was checked exhaustively to
    agree with exact arithmetic (the closest such direction is ~5e-7, relative, away from an
    irrational boundary: 8x the float32 rounding), and likewise for images with values k/4;
    rational boundaries (45 / 90 degrees) are compared exactly.  For arbitrary float input the
    result is exact up to float32 rounding of the ratio (atan2 in float32 would be no better).
    """
    thresholds, _ = _orientation_tables(n_orients)
    n_q = len(thresholds) + 1
    code = np.empty(gx.shape, np.uint8) if out is None else out
    flag = _scratch("flag", gx.shape, np.bool_)
    ratio = _scratch("ratio", gx.shape, np.float32)
    np.less(gy, 0, out=code.view(np.bool_))
    code += code
    code += np.less(gx, 0, out=flag)
    code *= np.uint8(n_q)  # quadrant * n_q
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(gy, gx, out=ratio)  # +-inf for vertical gradients, nan for zero gradients
    np.abs(ratio, out=ratio)
    for t in thresholds:
        code += np.greater(ratio, np.float32(t), out=flag)
    return code


def _orientation_bins(gx: np.ndarray, gy: np.ndarray, n_orients: int = 9) -> np.ndarray:
    """Contrast-sensitive bin (uint8, ``0 .. 2n-1``) of every gradient direction (gx, gy).

    Equals ``int(theta * 2n / 2pi + 0.5) mod 2n`` with ``theta = atan2(gy, gx)`` in
    ``[0, 2pi)``, evaluated exactly (the histogram uses the code directly; handy for tests).
    """
    _, table = _orientation_tables(n_orients)
    gx = np.asarray(gx, np.float32)
    gy = np.asarray(gy, np.float32)
    return table[_orientation_code(gx, gy, n_orients)]


# --------------------------------------------------------------------------------------------
# 2b. The release's approximate arithmetic (``arithmetic="release"``)
# --------------------------------------------------------------------------------------------

#: The toolbox's ``PI`` (``3.14159265f``) and its acos table: ``a[i] ~ acos(i / 10000)`` for
#: ``i = -10000 .. 9999`` plus 10 entries of padding on either side.
_PI_F32 = np.float32(3.14159265)
_ACOS_N = 10000
_ACOS_PAD = 10
_ACOS_OFFSET = _ACOS_N + _ACOS_PAD  # array index of i = 0
_ACOS_LEN = 2 * _ACOS_OFFSET

#: ``min(rsqrt(m2), 1e10f)`` on the doubled gradient's ``4 m2``: the cap halves too.
_HALF_RSQRT_CAP = np.float32(5e9)
_SIGN_BIT = np.uint32(0x80000000)
#: The modelled rsqrt keeps 13 significant bits (12 of float64's 52 fraction bits): add half a
#: unit of the last kept bit, then clear the 40 dropped bits.
_RSQRT_DROPPED_BITS = 52 - 12
_RSQRT_HALF_UNIT = np.int64(1 << (_RSQRT_DROPPED_BITS - 1))
_RSQRT_MASK = np.int64(~((1 << _RSQRT_DROPPED_BITS) - 1))
#: ``Gx * _m * 10000`` on the doubled gradient and the halved ``_m``: same real product.
_ACOS_MULT = np.float32(_ACOS_N)


@lru_cache(maxsize=1)
def _release_acos_table() -> np.ndarray:
    """The toolbox's ``acosTable()``: float32 ``a[i + 10010]`` for ``i = -10010 .. 10009``.

    ``a[i] = float(acos(i / 10000.f))`` for ``-10000 <= i < 10000``, ``PI`` below, ``0`` above,
    then every entry with ``i < 1000`` larger than ``PI - 1e-6f`` is clamped to ``PI - 1e-6f``
    (float32 arithmetic throughout; in effect ``i = -10010 .. -10000``).
    """
    i = np.arange(-_ACOS_OFFSET, _ACOS_OFFSET)
    inside = (i >= -_ACOS_N) & (i < _ACOS_N)
    x = i[inside].astype(np.float32) / np.float32(_ACOS_N)  # float32 division, as in C
    table = np.zeros(_ACOS_LEN, np.float32)
    table[i < -_ACOS_N] = _PI_F32
    table[inside] = np.arccos(x.astype(np.float64)).astype(np.float32)
    limit = _PI_F32 - np.float32(1e-6)
    table[(i < _ACOS_N // 10) & (table > limit)] = limit
    table.setflags(write=False)
    return table


@lru_cache(maxsize=16)
def _release_bin_table(n_orients: int) -> np.ndarray:
    """Contrast-sensitive bin (uint8) of every acos-table key, ``(2, 20020)`` flattened.

    Key ``k = i + 10010 + 20020 * [gy < 0]`` with ``i`` the truncated table index: the
    toolbox's orientation is ``O = a[i] (+ PI if gy < 0)`` and its bin (``gradQuantize``,
    non-interpolating) ``o0 = (int)(O * oMult + 0.5f)`` with ``oMult = (float)2n / (2 * PI)``,
    ``o0 = 0`` if ``o0 >= 2n``, all in float32.  Tabulating the bin per key replaces four
    float passes per pixel by one lookup.
    """
    table = _release_acos_table()
    n_bins = 2 * n_orients
    o_mult = np.float32(n_bins) / (np.float32(2) * _PI_F32)
    theta = np.concatenate([table, table + _PI_F32])  # float32 sums
    bins = (theta * o_mult + np.float32(0.5)).astype(np.int64)  # >= 0: truncation
    bins[bins >= n_bins] = 0
    out = bins.astype(np.uint8)
    out.setflags(write=False)
    return out


def _release_orientation(
    gx: np.ndarray,
    gy: np.ndarray,
    mag2: np.ndarray,
    n_orients: int,
    plane: int,
    tables: SSETables | None = None,
) -> np.ndarray:
    """Flat orientation-plane offset (int32, ``N * h0 * w0``) of every pixel, release arithmetic.

    On entry ``gx``, ``gy``, ``mag2`` are the *doubled* gradient and ``4 m2``; on exit
    ``mag2`` holds the capped approximate ``rsqrt(4 m2) = _m / 2`` (``_release_magnitude``
    turns it into ``2 M``).  Toolbox ``gradMag``: ``_m = min(rsqrt(m2), 1e10f)``,
    ``Gx = gx * _m * 10000`` (float32, in that order), Gx's sign flipped where gy's *sign bit*
    is set (so ``gy = -0.0`` flips too), ``i = (int) Gx`` (truncation), ``O = a[i]``, plus
    ``PI`` where ``gy < 0`` (false for -0.0).  Since ``(2 gx) * (_m / 2) == gx * _m`` exactly,
    every rounding is the toolbox's.  ``rsqrt`` is the model (``_release_rsqrt``) or, with
    ``tables``, the measured instruction (exact for ``4 m2`` too: it scales with the exponent).
    """
    rsqrt = _release_rsqrt if tables is None else tables.rsqrt_into
    half_m = rsqrt(mag2, out=mag2)
    start = _scratch("start", (gx.size,), np.int32)
    _release_keys(gx.reshape(-1), gy.reshape(-1), half_m.reshape(-1),
                  _release_plane_offsets(n_orients, plane), start)
    return start


@kernel
def _release_keys(gx, gy, half_m, offsets, start):  # pragma: no cover - compiled
    """``_release_orientation``'s per-pixel steps after ``rsqrt``, in one pass.

    ``half_m = min(half_m, cap)`` (in place, as the magnitude needs it), ``t = (gx half_m)
    10000`` in float32, negated where gy's sign bit is set (negation flips exactly that bit),
    clipped to the table, truncated toward zero, offset into the ``gy < 0`` half of the table
    where ``gy < 0``, and looked up in ``offsets``. A NaN (impossible for finite pixels) reads
    the table's centre.
    """
    cap = np.float32(_HALF_RSQRT_CAP)
    mult = np.float32(_ACOS_MULT)
    lo, hi = np.float32(-_ACOS_OFFSET), np.float32(_ACOS_OFFSET - 1)
    # Written without branches (the sign flip is a product with +-1, exact): with real
    # gradients their outcomes are random, and mispredictions doubled the fused kernel's time.
    for p in range(gx.size):
        hm = min(half_m[p], cap)
        half_m[p] = hm
        t = (gx[p] * hm) * mult
        t = t * np.float32(math.copysign(1.0, gy[p]))
        t = max(min(t, hi), lo)
        key = (int(t) if t == t else 0) + _ACOS_OFFSET
        key += _ACOS_LEN if gy[p] < 0 else 0
        start[p] = offsets[key]


@lru_cache(maxsize=16)
def _release_plane_offsets(n_orients: int, plane: int) -> np.ndarray:
    """``_release_bin_table`` times the accumulator's plane size (int32, cached per layout)."""
    offsets = _release_bin_table(n_orients).astype(np.int32) * np.int32(plane)
    offsets.setflags(write=False)
    return offsets


def _release_magnitude(half_m: np.ndarray, tables: SSETables | None = None) -> np.ndarray:
    """``2 M = 2 rcp(_m) = rcp(_m / 2)``, in place (input: ``_release_orientation``'s output)."""
    if tables is not None:
        return tables.rcp_into(half_m, out=half_m)
    return _release_rcp(half_m, out=half_m)


def _release_rsqrt(x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Model of SSE ``_mm_rsqrt_ps``: ``1 / sqrt(x)`` rounded to 13 significant bits.

    Evaluated in float64 (error < 2^-52, far from any rounding boundary: ``1 / sqrt(x)`` of a
    float32 ``x`` is never a 13-bit midpoint), then rounded to nearest by adding half a unit of
    the 13th bit to the bit pattern and clearing the 40 bits below; exact in float32.  ``x = 0``
    gives ``inf`` (as the instruction does).  See ``fhog`` for why this model.
    """
    v = _scratch("rel_f64", x.shape, np.float64)
    np.copyto(v, x)
    np.sqrt(v, out=v)
    with np.errstate(divide="ignore"):
        np.divide(1.0, v, out=v)
    bits = v.view(np.int64)
    bits += _RSQRT_HALF_UNIT
    bits &= _RSQRT_MASK  # inf stays inf: its low bits are zero and the carry stops there
    np.copyto(out, v, casting="same_kind")
    return out


def _release_rcp(x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Model of SSE ``_mm_rcp_ps``: correctly rounded float32 ``1 / x`` (see ``fhog``)."""
    with np.errstate(divide="ignore"):
        return np.divide(np.float32(1), x, out=out)


@lru_cache(maxsize=16)
def _voting_layout(
    n_img: int, hb: int, wb: int, cell: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Target-cell index and bilinear voting weights of every pixel of the ``(h0, w0)`` crop.

    For pixel column ``x``: ``xb = (x + 0.5) / cell - 0.5``; it votes ``1 - xd`` into cell
    column ``floor(xb)`` and ``xd = xb - floor(xb)`` into the next one; same for rows; the four
    products weight the four target cells.  Returns:

    * ``index`` (int32, ``N * h0 * w0``): the first (upper-left) target cell in one orientation
      plane of the accumulator, laid out ``(N, hb + 1, wb + 1)``: one padding row / column on
      top / left holds the votes for the non-existent cells -1 (which the toolbox drops too);
      votes for cells hb / wb wrap into the next padding column / row and are dropped as well;
    * ``w_top``, ``w_bottom`` (complex64, ``h0 * w0``): the weights for the first and second
      target row, with the left / right target column in the real / imaginary part.

    The weights include the toolbox's ``1 / cell^2`` and the 1/2 undoing the doubled gradients.
    Everything depends only on the position modulo ``cell`` and the shape, hence the cache.
    """
    pos = (np.arange(cell) + 0.5) / cell - 0.5
    first = np.floor(pos)  # -1 or 0: offset of the first target cell
    frac = pos - first
    row0 = (np.arange(hb).repeat(cell) + np.tile(first, hb) + 1).astype(np.int64)
    col0 = (np.arange(wb).repeat(cell) + np.tile(first, wb) + 1).astype(np.int64)
    base = (row0[:, None] * (wb + 1) + col0[None, :]).reshape(-1)
    img_off = np.arange(n_img, dtype=np.int64) * ((hb + 1) * (wb + 1))
    index = (img_off[:, None] + base[None, :]).reshape(-1).astype(np.int32)

    wy = np.tile(np.stack([1.0 - frac, frac]), (1, hb))  # (2, h0): first / second target row
    wx = np.tile(np.stack([1.0 - frac, frac]), (1, wb))  # (2, w0): first / second column
    scale = 0.5 / (cell * cell)
    wx_c = wx[0] + 1j * wx[1]
    w_top, w_bottom = (
        (scale * wy[a][:, None] * wx_c[None, :]).astype(np.complex64).reshape(-1) for a in range(2)
    )
    for arr in (index, w_top, w_bottom):
        arr.setflags(write=False)
    return index, w_top, w_bottom


@lru_cache(maxsize=4)
def _pixel_index(npix: int) -> np.ndarray:
    """``arange(npix)`` as read-only int32 (cached: used on every cell_size=1 call)."""
    index = np.arange(npix, dtype=np.int32)
    index.setflags(write=False)
    return index


def _histogram(
    gx: np.ndarray,
    gy: np.ndarray,
    mag2: np.ndarray,
    cell: int,
    n_orients: int,
    out: np.ndarray,
    release: bool = False,
    tables: SSETables | None = None,
) -> None:
    """Toolbox ``gradHist`` (hard orientation, bilinear spatial) into ``out`` ``(2n, N, hb, wb)``.

    Orientation-major ("planar") so that the normalisation can broadcast over whole planes.
    ``mag2`` is overwritten.  ``release`` selects the toolbox's approximate magnitude and
    acos-table orientation (see ``_release_orientation``) instead of the exact ones, with the
    SSE instructions replayed from ``tables`` if given, else modelled.
    """
    n_img, h0, w0 = gx.shape
    hb, wb = h0 // cell, w0 // cell
    n_bins = 2 * n_orients
    npix = n_img * h0 * w0
    plane = npix if cell == 1 else n_img * (hb + 1) * (wb + 1)
    size = n_bins * plane
    if size + wb + 2 >= 2**31:
        raise ValueError("fhog: batch too large for int32 histogram indices; split it")

    if release:
        # Flat index of each pixel's orientation plane straight from the acos-table key.
        start = _release_orientation(gx, gy, mag2, n_orients, plane, tables)
        mag = _release_magnitude(mag2, tables).reshape(n_img, h0 * w0)  # 2 * M
    else:
        # Flat index of each pixel's orientation plane (via the code -> bin table).
        _, table = _orientation_tables(n_orients)
        offsets = table.astype(np.int32) * np.int32(plane)
        code = _orientation_code(gx, gy, n_orients, _scratch("code", gx.shape, np.uint8))
        start = cv2.LUT(
            code.reshape(n_img * h0, w0), offsets, _scratch("start", (n_img * h0, w0), np.int32)
        ).reshape(-1)
        mag = np.sqrt(mag2, out=mag2).reshape(n_img, h0 * w0)  # 2 * M

    if cell == 1:
        # Every pixel is its own cell (xb = x, no spatial interpolation, as in the toolbox's
        # bin == 1 branch): a plain scatter, no accumulation needed.
        np.add(start, _pixel_index(npix), out=start)
        mag *= np.float32(0.5)
        out.fill(0.0)
        out.reshape(-1)[start] = mag.reshape(-1)
    else:
        index, w_top, w_bottom = _voting_layout(n_img, hb, wb, cell)
        acc = _scratch("acc", (2, size + wb + 2), np.float32)
        _vote(start, index, mag.reshape(-1), w_top, w_bottom, wb, acc, out)  # rescales too
        return
    _rescale_border(out)


def _rescale_border(out: np.ndarray) -> None:
    """Border cells of ``(2n, N, hb, wb)`` histograms only collect 7/8 of an interior cell's
    weight: rescale them, sequentially like the toolbox, so a single row / column gets the
    factor twice."""
    hb, wb = out.shape[2:]
    s = np.float32(8.0 / 7.0)
    if hb > 1:
        out[:, :, :: hb - 1] *= s  # first and last row
    else:
        out *= s * s
    if wb > 1:
        out[:, :, :, :: wb - 1] *= s  # first and last column
    else:
        out *= s * s


@kernel
def _vote(start, index, mag, w_top, w_bottom, wb, acc, out):  # pragma: no cover - compiled
    """Bilinear spatial voting of every pixel's ``2 M`` into its orientation plane.

    ``start`` (int32, N h0 w0): the pixel's orientation-plane offset; ``index``: its first
    target cell in the padded ``(N, hb + 1, wb + 1)`` plane (``_voting_layout``); ``w_top`` /
    ``w_bottom`` (complex64, h0 w0): the weights of the first / second target row, left column
    in the real part, right column in the imaginary part. ``acc`` (2, plane size + wb + 2) is
    scratch: left- and right-column votes. Every accumulator cell receives its votes in pixel
    order, first row's pass before the second row's, so each float32 sum is rounded exactly as
    the earlier ``np.add.at`` formulation rounded it. Writes ``out`` ``(2n, N, hb, wb)``.
    """
    hw = w_top.shape[0]
    n_img = start.shape[0] // hw
    left, right = acc[0], acc[1]
    left[:] = 0.0
    right[:] = 0.0
    for row_offset, weights in ((0, w_top), (wb + 1, w_bottom)):
        for i in range(n_img):
            for q in range(hw):
                p = i * hw + q
                k = start[p] + index[p] + row_offset
                w = weights[q]
                m = mag[p]
                left[k] += m * w.real
                right[k] += m * w.imag
    _combine_votes(left, right, wb, out)  # includes _rescale_border


@kernel
def _combine_votes(left, right, wb, out):  # pragma: no cover - compiled
    """Cell (i, j) = left votes at padded (i + 1, j + 1) + right votes at padded (i + 1, j),
    then ``_rescale_border``'s factors, with the same float32 products in the same order
    (rows first, then columns; ``(8/7)^2`` rounded once where the grid is one cell wide)."""
    n_bins, n_img, hb, _ = out.shape
    plane = n_img * (hb + 1) * (wb + 1)
    s = np.float32(8.0 / 7.0)
    s2 = s * s
    for o in range(n_bins):
        for i in range(n_img):
            for y in range(hb):
                base = o * plane + (i * (hb + 1) + y + 1) * (wb + 1)
                row = out[o, i, y]
                for x in range(wb):
                    row[x] = left[base + x + 1] + right[base + x]
                if hb == 1:
                    for x in range(wb):
                        row[x] = row[x] * s2
                elif y == 0 or y == hb - 1:
                    for x in range(wb):
                        row[x] = row[x] * s
                if wb == 1:
                    row[0] = row[0] * s2
                else:
                    row[0] = row[0] * s
                    row[wb - 1] = row[wb - 1] * s


def _release_histogram(
    x: np.ndarray, cell: int, n_orients: int, out: np.ndarray, reverse: bool = False
) -> None:
    """``_dominant_gradient`` + ``_histogram(release=True)`` with the modelled SSE arithmetic,
    fused into one pass over the pixels (``_release_votes``): the same bits, without the
    seven full-size intermediates that the separate steps write and read back. ``reverse``
    (uint8 colour images only): read the channels last to first (BGR as RGB).
    """
    n_img, hb, wb = out.shape[1:]
    plane = n_img * (hb + 1) * (wb + 1)
    size = 2 * n_orients * plane
    if size + wb + 2 >= 2**31:
        raise ValueError("fhog: batch too large for int32 histogram indices; split it")
    row_base, col0, w_top, w_bottom = _voting_rows(hb, wb, cell)
    acc = _scratch("acc", (2, size + wb + 2), np.float32)
    if x.dtype == np.uint8:
        bins, mags = _release_pixel_tables(n_orients)
    else:  # gradients are not small integers: the kernel computes each pixel's arithmetic
        bins, mags = _NO_BINS, _NO_MAGS
        if reverse:
            raise ValueError("_release_histogram: reverse is for uint8 images")
    # the kernel also applies _rescale_border
    _release_votes(np.ascontiguousarray(x), 0, _band_order(hb, cell), row_base, col0, w_top,
                   w_bottom, _release_plane_offsets(n_orients, plane), bins, mags, plane, hb,
                   wb, cell, reverse, acc, out)


def _release_fhog_uint8(
    x: np.ndarray, step: int, cell: int, n_orients: int, clip: float, window: np.ndarray,
    reverse: bool, out: np.ndarray,
) -> None:
    """``fhog``'s chunk loop for uint8 images in the release arithmetic, in one compiled call
    (``_release_chunks``): each chunk of ``step`` images through ``_release_histogram``'s
    kernel and ``_normalise``'s, the same calls on the same scratch, so the same bits.

    Why: the trackers' 200x200 patches go one per chunk, and the Python between the kernels
    (scratch views, cached tables, two dispatches with 16 arguments) cost ~40 µs a patch, six
    patches a frame.
    """
    n_img = x.shape[0]
    hb, wb = out.shape[1:3]
    n_chunk = min(step, n_img)
    plane = n_chunk * (hb + 1) * (wb + 1)
    size = 2 * n_orients * plane
    if size + wb + 2 >= 2**31:
        raise ValueError("fhog: batch too large for int32 histogram indices; split it")
    row_base, col0, w_top, w_bottom = _voting_rows(hb, wb, cell)
    acc = _scratch("acc", (2 * (size + wb + 2),), np.float32)
    r = _scratch("r", (3 * n_orients * n_chunk * hb * wb,), np.float32)
    bins, mags = _release_pixel_tables(n_orients)
    eps, half_clip, texture = _normalisation_constants(cell, clip)
    _release_chunks(np.ascontiguousarray(x), step, _band_order(hb, cell), row_base, col0,
                    w_top, w_bottom, _NO_OFFSETS, bins, mags, hb, wb, cell, reverse, n_orients,
                    eps, half_clip, texture, np.ascontiguousarray(window).reshape(-1), acc, r,
                    out)


_NO_OFFSETS = np.zeros(0, np.int32)  # the tabulated kernel reads bins, not offsets


@kernel
def _release_chunks(
    x, step, rows, row_base, col0, w_top, w_bottom, offsets, bins, mags, hb, wb, cell, reverse,
    n, eps, half_clip, texture, window, acc, r, out
):  # pragma: no cover - compiled
    """``fhog``'s per-chunk ``_release_histogram`` + ``_normalise``, for all chunks: ``acc`` and
    ``r`` are flat scratch, shaped per chunk as those functions shape theirs."""
    n_img = x.shape[0]
    cells = hb * wb
    for i0 in range(0, n_img, step):
        n_chunk = min(step, n_img - i0)
        plane = n_chunk * (hb + 1) * (wb + 1)
        size = 2 * n * plane + wb + 2
        chunk_acc = acc[: 2 * size].reshape(2, size)
        chunk_r = r[: 3 * n * n_chunk * cells].reshape(3 * n, n_chunk * cells)
        r1 = chunk_r[: 2 * n].reshape(2 * n, n_chunk, hb, wb)
        _release_votes(x, i0, rows, row_base, col0, w_top, w_bottom, offsets, bins, mags, plane,
                       hb, wb, cell, reverse, chunk_acc, r1)
        _normalise_cells(chunk_r.reshape(3 * n, n_chunk, hb, wb), n, eps, half_clip, texture,
                         window, out[i0: i0 + n_chunk])


#: The largest doubled gradient component of a uint8 image: ``2 (255 - 0)`` on the border
#: (interior differences stay within +-255).
_MAX_GRADIENT = 510
_GRADIENT_SPAN = 2 * _MAX_GRADIENT + 1
_NO_BINS = np.zeros(0, np.uint8)
_NO_MAGS = np.zeros(0, np.float32)


@lru_cache(maxsize=4)
def _release_pixel_tables(n_orients: int) -> tuple[np.ndarray, np.ndarray]:
    """Every possible pixel of a uint8 image, through the modelled release arithmetic.

    Returns ``bins`` (uint8) and ``mags`` (float32, ``2 M``), both indexed by
    ``(gy + 510) * 1021 + (gx + 510)`` for the doubled gradient ``gx``, ``gy``.

    Why: on uint8 pixels the doubled gradient components are integers in [-510, 510] (never
    ``-0.0``: ``x - x = +0``), and a pixel's orientation bin and magnitude depend on nothing
    else. Tabulating them with the very functions the per-pixel path calls makes the kernel's
    work per pixel two lookups instead of a float64 ``1 / sqrt``, two roundings and the key
    arithmetic: the same bits (by construction, and pinned by the golden hashes), at 0.6x the
    kernel's time. Natural images' gradients are small, so the lookups stay in a few
    kilobytes around the tables' centre. Built once per process in ~20 ms; 5 MB.
    """
    g = np.arange(-_MAX_GRADIENT, _MAX_GRADIENT + 1, dtype=np.float32)
    bins = np.empty((_GRADIENT_SPAN, _GRADIENT_SPAN), np.uint8)
    mags = np.empty((_GRADIENT_SPAN, _GRADIENT_SPAN), np.float32)
    offsets = _release_plane_offsets(n_orients, 1)
    rows = 64  # a few rows of the table at a time: the model's scratch stays small
    for top in range(0, _GRADIENT_SPAN, rows):
        gy = np.repeat(g[top : top + rows], _GRADIENT_SPAN)
        gx = np.tile(g, len(gy) // _GRADIENT_SPAN)
        m2 = gy * gy + gx * gx  # exact: integers below 2^24, as the kernel's fma gives them
        half_m = _release_rsqrt(m2, out=m2)
        start = np.empty(gx.size, np.int32)
        _release_keys(gx, gy, half_m, offsets, start)
        bins[top : top + rows] = start.reshape(-1, _GRADIENT_SPAN)
        mags[top : top + rows] = _release_rcp(half_m, out=half_m).reshape(-1, _GRADIENT_SPAN)
    bins, mags = bins.reshape(-1), mags.reshape(-1)
    for arr in (bins, mags):
        arr.setflags(write=False)
    return bins, mags


@lru_cache(maxsize=64)
def _voting_rows(
    hb: int, wb: int, cell: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``_voting_layout`` of one image, factored: its target index is ``row_base[y] +
    col0[x]`` (int64 ``(h0,)``, int32 ``(w0,)``) and its weights depend on the row only through
    ``y % cell``, so ``w_top`` / ``w_bottom`` are ``(cell, w0)``: the same values, read from a
    few kilobytes instead of three arrays the size of the image."""
    index, w_top, w_bottom = _voting_layout(1, hb, wb, cell)
    h0, w0 = hb * cell, wb * cell
    index = index.reshape(h0, w0)
    col0 = (index[0] - index[0, 0]).astype(np.int32)
    row_base = index[:, 0].astype(np.int64)
    assert np.array_equal(index, row_base[:, None] + col0[None, :])
    w_top, w_bottom = (w.reshape(h0, w0)[:cell].copy() for w in (w_top, w_bottom))
    for arr in (row_base, col0, w_top, w_bottom):
        arr.setflags(write=False)
    return row_base, col0, w_top, w_bottom


@lru_cache(maxsize=64)
def _band_order(hb: int, cell: int) -> np.ndarray:
    """Pixel rows ordered by the first cell row they vote into, last band first, rows of a band
    in increasing order.

    Why: ``_vote`` adds every pixel's upper votes before any lower vote. A cell row receives its
    upper votes from one band of pixel rows and its lower votes from the band above, so running
    the bands bottom-up, each pixel voting up and down at once, gives every cell its votes in
    the same order, hence the same float32 sums.
    """
    pos = (np.arange(cell) + 0.5) / cell - 0.5
    first = (np.arange(hb).repeat(cell) + np.tile(np.floor(pos), hb)).astype(np.int64)
    order = np.lexsort((np.arange(hb * cell), -first)).astype(np.int64)
    order.setflags(write=False)
    return order


@kernel
def _release_votes(
    x, i0, rows, row_base, col0, w_top, w_bottom, offsets, bins, mags, plane, hb, wb, cell,
    reverse, acc, out
):  # pragma: no cover - compiled
    """Per pixel row (in ``_band_order``): the dominant gradient (``_gradient_row``), the
    modelled ``rsqrt`` (``_release_rsqrt``: float64 ``1 / sqrt``, rounded to 13 bits, capped),
    ``2 M = rcp(_m / 2)`` (``_release_rcp``), the release's orientation key
    (``_release_keys``, which re-applies the cap: a no-op) and both bilinear votes (``_vote``,
    its layout read in the factored form of ``_voting_rows``), each with the same float32
    operations as the separate step it replaces; then ``_combine_votes``.

    With ``bins`` and ``mags`` from ``_release_pixel_tables`` (uint8 images), the gradient is
    taken in integers (``_gradient_index_row``) and each pixel's bin and ``2 M`` are read from
    the tables instead of computed; ``plane`` is the accumulator's plane size, which
    ``offsets`` (used otherwise) already includes.
    """
    _, height, width, channels = x.shape
    n_img = out.shape[1]  # images i0 .. i0 + n_img - 1 of x
    w0 = wb * cell
    img_cells = (hb + 1) * (wb + 1)  # one image's padded plane
    tabulated = bins.size > 0
    # the integer path reads uint8 planes, the per-pixel path float32 ones
    byte_shape = (channels, height, width) if tabulated else (0, 0, 0)
    float_shape = (0, 0, 0) if tabulated else (channels, height, width)
    byte_planes = np.empty(byte_shape, np.uint8)
    planes = np.empty(float_shape, np.float32)
    work = np.empty((3, w0), np.float32)
    int_dx = np.empty(w0, np.int32)
    int_dy = np.empty(w0, np.int32)
    int_best = np.empty(w0, np.int32)
    gx = np.empty(w0, np.float32)
    gy = np.empty(w0, np.float32)
    m2 = np.empty(w0, np.float32)
    inv = np.empty(w0, np.float64)
    bits = inv.view(np.int64)
    half_m = np.empty(w0, np.float32)
    mag = np.empty(w0, np.float32)
    start = np.empty(w0, np.int32)
    index = np.empty(w0, np.int32)
    left, right = acc[0], acc[1]
    left[:] = 0.0
    right[:] = 0.0
    cap = np.float32(_HALF_RSQRT_CAP)
    second = wb + 1
    # One simple loop per step, which LLVM vectorises (measured: one loop doing all the steps
    # per pixel ran at half the speed).
    for i in range(n_img):
        if tabulated:
            _channel_planes(x, i0 + i, reverse, byte_planes)
        else:
            _channel_planes(x, i0 + i, False, planes)
        for y in rows:
            if tabulated:
                _gradient_index_row(byte_planes, y, int_dx, int_dy, int_best, index)
                for col in range(w0):
                    mag[col] = mags[index[col]]
                for col in range(w0):
                    start[col] = np.int32(bins[index[col]]) * plane
            else:
                _gradient_row(planes, y, work, gx, gy, m2)
                for col in range(w0):
                    inv[col] = 1.0 / math.sqrt(np.float64(m2[col]))  # 0 -> inf, as the model
                for col in range(w0):
                    bits[col] = (bits[col] + _RSQRT_HALF_UNIT) & _RSQRT_MASK
                for col in range(w0):
                    half_m[col] = min(np.float32(inv[col]), cap)
                for col in range(w0):
                    mag[col] = np.float32(1.0) / half_m[col]
                _release_keys(gx, gy, half_m, offsets, start)
            base = i * img_cells + row_base[y]
            top = w_top[y % cell]
            bottom = w_bottom[y % cell]
            for col in range(w0):
                k = start[col] + base + col0[col]
                m = mag[col]
                w = top[col]
                left[k] += m * w.real
                right[k] += m * w.imag
                w = bottom[col]
                left[k + second] += m * w.real
                right[k + second] += m * w.imag
    _combine_votes(left, right, wb, out)


# --------------------------------------------------------------------------------------------
# 3. Block normalisation and the output channels
# --------------------------------------------------------------------------------------------


def _normalise(
    r: np.ndarray,
    n_img: int,
    hb: int,
    wb: int,
    cell: int,
    n_orients: int,
    clip: float,
    window: np.ndarray,
    out: np.ndarray,
) -> None:
    """Toolbox ``hogNormMatrix`` + ``hogChannels``: ``r`` ``(3n, N*hb*wb)`` -> ``out``, times
    ``window`` (``fhog``'s; empty: none).

    ``out`` is a ``(N, hb, wb, 3n + 4)`` float32 array (channels last), any strides.

    ``r[:2n]`` holds R1 on entry; ``r[2n:]`` is scratch. The 1/2 of the orientation channels
    is folded into the normalisers and the clip value (exact: a power of two), which saves a
    multiplication per value.
    """
    eps, half_clip, texture = _normalisation_constants(cell, clip)
    _normalise_cells(r.reshape(3 * n_orients, n_img, hb, wb), n_orients, eps, half_clip,
                     texture, np.ascontiguousarray(window).reshape(-1), out)


def _normalisation_constants(
    cell: int, clip: float
) -> tuple[np.float32, np.float32, np.float32]:
    """``_normalise_cells``' float32 constants: the block energy's epsilon, half the clip value
    (the 1/2 of the orientation channels folded in) and the texture channels' weight, doubled."""
    eps = np.float32(1e-4) / 4 / cell / cell / cell / cell
    half_clip = np.float32(0.5 * float(np.float32(clip)))
    return eps, half_clip, np.float32(2.0) * _TEXTURE_WEIGHT


@kernel
def _normalise_cells(r, n, eps, half_clip, texture, window, out):  # pragma: no cover - compiled
    """``_normalise``'s kernel, plane by plane.

    R2 = R1[o] + R1[o + n]; each 2x2 block's energy is the float32 sum of its cells' squared
    R2 (summed in channel order, then the two rows, then the two columns); its halved
    normaliser ``0.5 / sqrt(energy + eps)``; blocks at the border are replicated (a 1-wide
    grid uses 1-wide "blocks"). Each output channel is ``sum_k min(R n_k, clip / 2)`` over the
    four blocks touching the cell, in the toolbox's order, and each texture channel ``k`` the
    sum over the 2n sensitive orientations of block ``k``'s truncated terms, times
    ``2 * 0.2357``, then each value times ``window`` (flat ``hb * wb``; empty: none). Every
    float32 operation is the one the earlier NumPy/OpenCV version made, in the same order, so
    the features are identical bit for bit.
    """
    n_bins = 2 * n
    _, n_img, hb, wb = r.shape
    hw = hb * wb
    nbr = hb - 1 if hb > 1 else hb
    nbc = wb - 1 if wb > 1 else wb
    energy = np.empty((hb, wb), np.float32)
    block = np.empty((nbr, nbc), np.float32)
    norms = np.empty((4, hb, wb), np.float32)
    terms = np.empty((3 * n, hw), np.float32)
    tex = np.empty((4, hw), np.float32)
    hc = half_clip
    windowed = window.size > 0
    for i in range(n_img):
        energy[:] = 0.0
        for o in range(n):
            for y in range(hb):
                for x in range(wb):
                    v = r[o, i, y, x] + r[o + n, i, y, x]
                    r[n_bins + o, i, y, x] = v
                    energy[y, x] += v * v
        for y in range(nbr):
            for x in range(nbc):
                e0 = energy[y, x] + energy[y + 1, x] if hb > 1 else energy[y, x]
                if wb > 1:
                    e1 = energy[y, x + 1] + energy[y + 1, x + 1] if hb > 1 else energy[y, x + 1]
                    e0 = e0 + e1
                block[y, x] = np.float32(0.5) / np.sqrt(e0 + eps)
        for k in range(4):
            for y in range(hb):
                by = min(max(y - 1, 0), nbr - 1) if k & 1 else min(y, nbr - 1)
                for x in range(wb):
                    bx = min(max(x - 1, 0), nbc - 1) if k & 2 else min(x, nbc - 1)
                    norms[k, y, x] = block[by, bx]
        nf = norms.reshape(4, hw)  # each cell's four block normalisers, plane by plane
        # Whole planes at a time, one array written per loop (LLVM vectorises these, not
        # loops over one row of cells nor loops that write several arrays).
        n0, n1, n2, n3 = nf[0], nf[1], nf[2], nf[3]
        for c in range(3 * n):
            rp = r[c, i].reshape(hw)
            tc = terms[c]
            for p in range(hw):
                v = rp[p]
                tc[p] = ((min(v * n0[p], hc) + min(v * n1[p], hc)) + min(v * n2[p], hc)) + min(
                    v * n3[p], hc)
            if c < n_bins:
                for k in range(4):
                    nk = nf[k]
                    xk = tex[k]
                    if c == 0:
                        for p in range(hw):
                            xk[p] = min(rp[p] * nk[p], hc)
                    else:
                        for p in range(hw):
                            xk[p] = xk[p] + min(rp[p] * nk[p], hc)
        if windowed:  # the same products as multiplying the maps afterwards
            for k in range(4):
                tk = tex[k]
                for p in range(hw):
                    tk[p] = tk[p] * texture * window[p]
            for c in range(3 * n):
                tc = terms[c]
                for p in range(hw):
                    tc[p] = tc[p] * window[p]
        else:
            for k in range(4):
                tk = tex[k]
                for p in range(hw):
                    tk[p] = tk[p] * texture
        for k in range(4):
            for y in range(hb):
                for x in range(wb):
                    out[i, y, x, 3 * n + k] = tex[k, y * wb + x]
        if out.strides[3] > out.strides[2]:
            for c in range(3 * n):
                for y in range(hb):
                    for x in range(wb):
                        out[i, y, x, c] = terms[c, y * wb + x]
        else:
            for y in range(hb):
                for x in range(wb):
                    for c in range(3 * n):
                        out[i, y, x, c] = terms[c, y * wb + x]
