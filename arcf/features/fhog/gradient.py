"""Step 1: the per-pixel gradient of the channel with the largest magnitude (doubled)."""

from __future__ import annotations

import numpy as np

from ..._jit import fma32, kernel
from .scratch import scratch

#: The largest doubled gradient component of a uint8 image: ``2 (255 - 0)`` on the border
#: (interior differences stay within +-255).
MAX_GRADIENT = 510
GRADIENT_SPAN = 2 * MAX_GRADIENT + 1


def dominant_gradient(
    x: np.ndarray, h0: int, w0: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Doubled gradient of the channel with the largest magnitude, cropped to ``(h0, w0)``.

    Returns three contiguous float32 scratch arrays ``(N, h0, w0)``: ``2 gx``, ``2 gy`` and
    ``4 (gx^2 + gy^2)`` (see ``_gradient_kernel``).
    """
    n_img = x.shape[0]
    gx, gy, m2 = (scratch(name, (n_img, h0, w0), np.float32) for name in ("gx", "gy", "m2"))
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
        channel_planes(x, i, False, planes)
        for r in range(h0):
            gradient_row(planes, r, work, gx[i, r], gy[i, r], m2[i, r])


@kernel
def channel_planes(x, i, reverse, planes):  # pragma: no cover - compiled
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
def gradient_row(planes, r, work, gx, gy, m2):  # pragma: no cover - compiled
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
def gradient_index_row(planes, r, dx, dy, best, index):  # pragma: no cover - compiled
    """Row ``r`` of ``gradient_row`` on uint8 planes, in int32, as the index of the pixel's
    doubled gradient in ``release_pixel_tables``: ``(gy + 510) * 1021 + gx + 510``.

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
    span, centre = GRADIENT_SPAN, MAX_GRADIENT * (GRADIENT_SPAN + 1)
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
