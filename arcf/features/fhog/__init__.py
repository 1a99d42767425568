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

This is the tracker's hottest code path (several ~200x200 patches per frame), so it works on
a batch of same-size images at once, in chunks whose intermediates fit in the L2 cache, with
compiled kernels and per-thread scratch buffers. The package holds one step per module:

* :mod:`.gradient`: step 1, the dominant channel's doubled gradient;
* :mod:`.orientation`: step 2's exact orientation bins, from sign tests and ratio thresholds
  (no ``atan2``, whose rounding misbins pixels on or near a boundary);
* :mod:`.release`: the release's approximate arithmetic (SSE ``rsqrt``/``rcp`` modelled or
  replayed, the acos table) and its tables of every possible uint8 pixel;
* :mod:`.voting`: step 2's bilinear spatial voting;
* :mod:`.fused`: the release arithmetic's steps 1-3 fused into one compiled pass per pixel row,
  bit for bit the separate steps' result;
* :mod:`.normalise`: step 3;
* :mod:`.scratch`: the scratch buffers and the chunk size.

Cell size 1 (tiny targets) skips spatial interpolation altogether, as the toolbox does.

``arithmetic="release"`` swaps step 1's exact magnitude and step 2's exact orientation for the
toolbox's SSE approximations (approximate reciprocal square root, acos lookup table), which is
what the authors' ARCF release computed; see :func:`fhog`.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from ..sse import SSEInstructions, SSETables
from .fused import release_fhog_uint8, release_histogram
from .gradient import dominant_gradient
from .normalise import normalise
from .release import SSE_MODEL, SSEModel
from .scratch import chunk_size, scratch
from .voting import histogram

__all__ = ["SSE_MODEL", "Arithmetic", "ArithmeticMode", "SSEModel", "fhog", "fhog_num_channels"]

#: ``fhog``'s arithmetic: exact gradient magnitude and orientation, or the authors' release's
#: approximations (SSE reciprocal square root, acos lookup table) with the SSE instructions
#: either modelled (``"release"``) or those of an :class:`~arcf.features.sse.SSEInstructions`
#: (a CPU's measured :class:`~arcf.features.sse.SSETables`, or :data:`SSE_MODEL`).
ArithmeticMode = Literal["exact", "release"]
Arithmetic = ArithmeticMode | SSEInstructions

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

            An :class:`~arcf.features.sse.SSEInstructions`: the release arithmetic with those
            instructions, e.g. an :class:`~arcf.features.sse.SSETables`, a CPU's own
            ``RSQRTPS`` / ``RCPPS`` replayed bit for bit from the tables that
            ``tools/sse_approx_dump.c`` measured on it (the package ships the AMD EPYC's
            that traced the release), or :data:`SSE_MODEL`, the model itself (the same bits as
            ``"release"``). uint8 images run fused with tables of every pixel built from the
            instructions; other pixels take the separate steps, which call them.
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
    instructions = _instructions(arithmetic)

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
    # The release arithmetic on cells of 2+ pixels runs fused: uint8 pixels read from tables of
    # every possible pixel (any instructions), other pixels computed with the model.
    tabulated = instructions is not None and cell_size > 1 and x.dtype == np.uint8
    computed = arithmetic == "release" and cell_size > 1 and not tabulated
    # the tabulated kernel reads BGR pixels in RGB order itself; elsewhere a reversed view
    reverse = bgr and channels == 3
    if reverse and not tabulated:
        x, reverse = x[..., ::-1], False
    result = out
    out = out.view()
    try:
        out.shape = (n_img, hb, wb, n_out)  # in place: raises where only a copy could do
    except AttributeError:
        out = np.empty((n_img, hb, wb, n_out), np.float32)
    step = chunk_size(height, width, hb, wb, n_orients)
    if tabulated:  # the trackers' case: one compiled call
        assert instructions is not None
        release_fhog_uint8(x, step, cell_size, n_orients, clip, window, reverse, instructions,
                           out)
    else:
        for i in range(0, n_img, step):
            chunk = x[i : i + step]
            n_chunk = chunk.shape[0]
            # R1 and (filled later) R2, orientation-major: (3n, N * hb * wb).
            r = scratch("r", (3 * n_orients, n_chunk * hb * wb), np.float32)
            r1 = r[: 2 * n_orients].reshape(2 * n_orients, n_chunk, hb, wb)
            if computed:
                release_histogram(chunk, cell_size, n_orients, out=r1)
            else:
                gx, gy, mag2 = dominant_gradient(chunk, hb * cell_size, wb * cell_size)
                histogram(gx, gy, mag2, cell_size, n_orients, out=r1, instructions=instructions)
            normalise(r, n_chunk, hb, wb, cell_size, n_orients, clip, window,
                      out=out[i : i + n_chunk])
    if not np.shares_memory(out, result):
        result[...] = out.reshape(shape)
    return result


def _instructions(arithmetic: Arithmetic) -> SSEInstructions | None:
    """The SSE instructions of the release arithmetic (None: exact arithmetic)."""
    if arithmetic == "exact":
        return None
    if arithmetic == "release":
        return SSE_MODEL
    if isinstance(arithmetic, SSETables | SSEModel) or (
            callable(getattr(arithmetic, "rsqrt_into", None))
            and callable(getattr(arithmetic, "rcp_into", None))):
        return arithmetic
    raise ValueError(f"fhog: arithmetic must be 'exact', 'release' or SSE instructions (an "
                     f"SSETables), got {arithmetic!r}")
