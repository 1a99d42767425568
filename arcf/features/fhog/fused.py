"""The release arithmetic fused: gradient, orientation, magnitude and both votes per pixel row
in one compiled pass, bit for bit the separate steps' result (the trackers' hot path)."""

from __future__ import annotations

import math

import numpy as np

from ..._jit import kernel
from ..sse import SSEInstructions
from .gradient import channel_planes, gradient_index_row, gradient_row
from .normalise import normalisation_constants, normalise_cells
from .release import (
    HALF_RSQRT_CAP,
    RSQRT_HALF_UNIT,
    RSQRT_MASK,
    release_keys,
    release_pixel_tables,
    release_plane_offsets,
)
from .scratch import scratch
from .voting import band_order, combine_votes, voting_rows

_NO_BINS = np.zeros(0, np.uint8)
_NO_MAGS = np.zeros(0, np.float32)

def release_histogram(x: np.ndarray, cell: int, n_orients: int, out: np.ndarray) -> None:
    """``dominant_gradient`` + ``histogram`` with the modelled SSE arithmetic (:data:`SSE_MODEL`)
    for images whose pixels are not uint8, fused into one pass over the pixels
    (``_release_votes``): the same bits, without the seven full-size intermediates that the
    separate steps write and read back.
    """
    n_img, hb, wb = out.shape[1:]
    plane = n_img * (hb + 1) * (wb + 1)
    size = 2 * n_orients * plane
    if size + wb + 2 >= 2**31:
        raise ValueError("fhog: batch too large for int32 histogram indices; split it")
    row_base, col0, w_top, w_bottom = voting_rows(hb, wb, cell)
    acc = scratch("acc", (2, size + wb + 2), np.float32)
    # gradients are not small integers: the kernel computes each pixel's arithmetic (the
    # model's); it also applies rescale_border
    _release_votes(np.ascontiguousarray(x, np.float32), 0, band_order(hb, cell), row_base, col0,
                   w_top, w_bottom, release_plane_offsets(n_orients, plane), _NO_BINS,
                   _NO_MAGS, plane, hb, wb, cell, False, acc, out)


def release_fhog_uint8(
    x: np.ndarray, step: int, cell: int, n_orients: int, clip: float, window: np.ndarray,
    reverse: bool, instructions: SSEInstructions, out: np.ndarray,
) -> None:
    """``fhog``'s chunk loop for uint8 images in the release arithmetic on ``instructions``, in
    one compiled call (``_release_chunks``): each chunk of ``step`` images through the voting
    kernel, its pixels read from ``release_pixel_tables``, and ``normalise``'s kernel, the
    same steps on the same scratch, so the same bits. ``reverse``: read colour channels last
    to first (BGR as RGB).

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
    row_base, col0, w_top, w_bottom = voting_rows(hb, wb, cell)
    acc = scratch("acc", (2 * (size + wb + 2),), np.float32)
    r = scratch("r", (3 * n_orients * n_chunk * hb * wb,), np.float32)
    bins, mags = release_pixel_tables(n_orients, instructions)
    eps, half_clip, texture = normalisation_constants(cell, clip)
    _release_chunks(np.ascontiguousarray(x), step, band_order(hb, cell), row_base, col0,
                    w_top, w_bottom, _NO_OFFSETS, bins, mags, hb, wb, cell, reverse, n_orients,
                    eps, half_clip, texture, np.ascontiguousarray(window).reshape(-1), acc, r,
                    out)


_NO_OFFSETS = np.zeros(0, np.int32)  # the tabulated kernel reads bins, not offsets


@kernel
def _release_chunks(
    x, step, rows, row_base, col0, w_top, w_bottom, offsets, bins, mags, hb, wb, cell, reverse,
    n, eps, half_clip, texture, window, acc, r, out
):  # pragma: no cover - compiled
    """``fhog``'s per-chunk ``release_histogram`` + ``normalise``, for all chunks: ``acc`` and
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
        normalise_cells(chunk_r.reshape(3 * n, n_chunk, hb, wb), n, eps, half_clip, texture,
                         window, out[i0: i0 + n_chunk])


@kernel
def _release_votes(
    x, i0, rows, row_base, col0, w_top, w_bottom, offsets, bins, mags, plane, hb, wb, cell,
    reverse, acc, out
):  # pragma: no cover - compiled
    """Per pixel row (in ``band_order``): the dominant gradient (``gradient_row``), the
    modelled ``rsqrt`` (``release_rsqrt``: float64 ``1 / sqrt``, rounded to 13 bits, capped),
    ``2 M = rcp(_m / 2)`` (``release_rcp``), the release's orientation key
    (``release_keys``, which re-applies the cap: a no-op) and both bilinear votes (``vote``,
    its layout read in the factored form of ``voting_rows``), each with the same float32
    operations as the separate step it replaces; then ``combine_votes``.

    With ``bins`` and ``mags`` from ``release_pixel_tables`` (uint8 images), the gradient is
    taken in integers (``gradient_index_row``) and each pixel's bin and ``2 M`` are read from
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
    cap = np.float32(HALF_RSQRT_CAP)
    second = wb + 1
    # One simple loop per step, which LLVM vectorises (measured: one loop doing all the steps
    # per pixel ran at half the speed).
    for i in range(n_img):
        if tabulated:
            channel_planes(x, i0 + i, reverse, byte_planes)
        else:
            channel_planes(x, i0 + i, False, planes)
        for y in rows:
            if tabulated:
                gradient_index_row(byte_planes, y, int_dx, int_dy, int_best, index)
                for col in range(w0):
                    mag[col] = mags[index[col]]
                for col in range(w0):
                    start[col] = np.int32(bins[index[col]]) * plane
            else:
                gradient_row(planes, y, work, gx, gy, m2)
                for col in range(w0):
                    inv[col] = 1.0 / math.sqrt(np.float64(m2[col]))  # 0 -> inf, as the model
                for col in range(w0):
                    bits[col] = (bits[col] + RSQRT_HALF_UNIT) & RSQRT_MASK
                for col in range(w0):
                    half_m[col] = min(np.float32(inv[col]), cap)
                for col in range(w0):
                    mag[col] = np.float32(1.0) / half_m[col]
                release_keys(gx, gy, half_m, offsets, start)
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
    combine_votes(left, right, wb, out)
