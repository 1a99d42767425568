"""Step 3: the four 2x2-block normalisations, truncation and the output channels (toolbox
``hogNormMatrix`` + ``hogChannels``)."""

from __future__ import annotations

import numpy as np

from ..._jit import kernel

#: Weight of the 4 texture (gradient-energy) channels, as in the toolbox (~ 1 / sqrt(18)).
_TEXTURE_WEIGHT = np.float32(0.2357)

def normalise(
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
    eps, half_clip, texture = normalisation_constants(cell, clip)
    normalise_cells(r.reshape(3 * n_orients, n_img, hb, wb), n_orients, eps, half_clip,
                     texture, np.ascontiguousarray(window).reshape(-1), out)


def normalisation_constants(
    cell: int, clip: float
) -> tuple[np.float32, np.float32, np.float32]:
    """``normalise_cells``' float32 constants: the block energy's epsilon, half the clip value
    (the 1/2 of the orientation channels folded in) and the texture channels' weight, doubled."""
    eps = np.float32(1e-4) / 4 / cell / cell / cell / cell
    half_clip = np.float32(0.5 * float(np.float32(clip)))
    return eps, half_clip, np.float32(2.0) * _TEXTURE_WEIGHT


@kernel
def normalise_cells(r, n, eps, half_clip, texture, window, out):  # pragma: no cover - compiled
    """``normalise``'s kernel, plane by plane.

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
