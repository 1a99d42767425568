"""Step 2: bilinear spatial voting of each pixel's magnitude into its orientation plane
(toolbox ``gradHist``, hard orientation), exact or release arithmetic."""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from ..._jit import kernel
from ..sse import SSEInstructions
from .orientation import orientation_code, orientation_tables
from .release import release_magnitude, release_orientation
from .scratch import scratch


@lru_cache(maxsize=16)
def voting_layout(
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
def pixel_index(npix: int) -> np.ndarray:
    """``arange(npix)`` as read-only int32 (cached: used on every cell_size=1 call)."""
    index = np.arange(npix, dtype=np.int32)
    index.setflags(write=False)
    return index


def histogram(
    gx: np.ndarray,
    gy: np.ndarray,
    mag2: np.ndarray,
    cell: int,
    n_orients: int,
    out: np.ndarray,
    instructions: SSEInstructions | None = None,
) -> None:
    """Toolbox ``gradHist`` (hard orientation, bilinear spatial) into ``out`` ``(2n, N, hb, wb)``.

    Orientation-major ("planar") so that the normalisation can broadcast over whole planes.
    ``mag2`` is overwritten.  With ``instructions``, the toolbox's approximate magnitude and
    acos-table orientation on those SSE instructions (see ``release_orientation``) instead of
    the exact ones.
    """
    n_img, h0, w0 = gx.shape
    hb, wb = h0 // cell, w0 // cell
    n_bins = 2 * n_orients
    npix = n_img * h0 * w0
    plane = npix if cell == 1 else n_img * (hb + 1) * (wb + 1)
    size = n_bins * plane
    if size + wb + 2 >= 2**31:
        raise ValueError("fhog: batch too large for int32 histogram indices; split it")

    if instructions is not None:
        # Flat index of each pixel's orientation plane straight from the acos-table key.
        start = release_orientation(gx, gy, mag2, n_orients, plane, instructions)
        mag = release_magnitude(mag2, instructions).reshape(n_img, h0 * w0)  # 2 * M
    else:
        # Flat index of each pixel's orientation plane (via the code -> bin table).
        _, table = orientation_tables(n_orients)
        offsets = table.astype(np.int32) * np.int32(plane)
        code = orientation_code(gx, gy, n_orients, scratch("code", gx.shape, np.uint8))
        start = cv2.LUT(
            code.reshape(n_img * h0, w0), offsets, scratch("start", (n_img * h0, w0), np.int32)
        ).reshape(-1)
        mag = np.sqrt(mag2, out=mag2).reshape(n_img, h0 * w0)  # 2 * M

    if cell == 1:
        # Every pixel is its own cell (xb = x, no spatial interpolation, as in the toolbox's
        # bin == 1 branch): a plain scatter, no accumulation needed.
        np.add(start, pixel_index(npix), out=start)
        mag *= np.float32(0.5)
        out.fill(0.0)
        out.reshape(-1)[start] = mag.reshape(-1)
    else:
        index, w_top, w_bottom = voting_layout(n_img, hb, wb, cell)
        acc = scratch("acc", (2, size + wb + 2), np.float32)
        vote(start, index, mag.reshape(-1), w_top, w_bottom, wb, acc, out)  # rescales too
        return
    rescale_border(out)


def rescale_border(out: np.ndarray) -> None:
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
def vote(start, index, mag, w_top, w_bottom, wb, acc, out):  # pragma: no cover - compiled
    """Bilinear spatial voting of every pixel's ``2 M`` into its orientation plane.

    ``start`` (int32, N h0 w0): the pixel's orientation-plane offset; ``index``: its first
    target cell in the padded ``(N, hb + 1, wb + 1)`` plane (``voting_layout``); ``w_top`` /
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
    combine_votes(left, right, wb, out)  # includes rescale_border


@kernel
def combine_votes(left, right, wb, out):  # pragma: no cover - compiled
    """Cell (i, j) = left votes at padded (i + 1, j + 1) + right votes at padded (i + 1, j),
    then ``rescale_border``'s factors, with the same float32 products in the same order
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


@lru_cache(maxsize=64)
def voting_rows(
    hb: int, wb: int, cell: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``voting_layout`` of one image, factored: its target index is ``row_base[y] +
    col0[x]`` (int64 ``(h0,)``, int32 ``(w0,)``) and its weights depend on the row only through
    ``y % cell``, so ``w_top`` / ``w_bottom`` are ``(cell, w0)``: the same values, read from a
    few kilobytes instead of three arrays the size of the image."""
    index, w_top, w_bottom = voting_layout(1, hb, wb, cell)
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
def band_order(hb: int, cell: int) -> np.ndarray:
    """Pixel rows ordered by the first cell row they vote into, last band first, rows of a band
    in increasing order.

    Why: ``vote`` adds every pixel's upper votes before any lower vote. A cell row receives its
    upper votes from one band of pixel rows and its lower votes from the band above, so running
    the bands bottom-up, each pixel voting up and down at once, gives every cell its votes in
    the same order, hence the same float32 sums.
    """
    pos = (np.arange(cell) + 0.5) / cell - 0.5
    first = (np.arange(hb).repeat(cell) + np.tile(np.floor(pos), hb)).astype(np.int64)
    order = np.lexsort((np.arange(hb * cell), -first)).astype(np.int64)
    order.setflags(write=False)
    return order
