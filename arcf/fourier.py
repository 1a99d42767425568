"""Fourier-domain helpers shared by the trackers: windows, labels, inverse FFTs, peak search.

Conventions: spatial maps are (..., H, W) with the origin at index (0, 0) (circularly shifted, as
the release stores its labels); "signed" indices run 0, 1, ..., ceil((n-1)/2), -floor((n-1)/2),
..., -1 as MATLAB's ``circshift(-floor((n-1)/2):ceil((n-1)/2), -floor((n-1)/2))`` produces.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from ._jit import fma32, kernel


def signed_indices(n: int) -> np.ndarray:
    """Integer offsets of the DFT grid in storage order: 0..ceil((n-1)/2), then negatives."""
    half = (n - 1) // 2
    return np.roll(np.arange(-half, n - half), -half)


def hann2d(shape: tuple[int, int]) -> np.ndarray:
    """The release's cosine window ``hann(h) * hann(w)'`` (MATLAB's symmetric Hann, zero ends).

    Returns float32 (H, W).
    """
    return np.outer(np.hanning(shape[0]), np.hanning(shape[1])).astype(np.float32)


def correlate(g_f: np.ndarray, x_f: np.ndarray) -> np.ndarray:
    """Response spectra ``Σ_d conj(ĝ_d) x̂_d`` of a filter ``(D, H, W')`` on samples ``(S, D, H,
    W')`` -> ``(S, H, W')``: the correlation of each sample with the filter (detection).

    Computed by a kernel with NumPy's own arithmetic (one FMA per part of each complex product,
    channels summed in order), so it equals ``np.sum(np.conj(g_f)[None] * x_f, axis=1)`` bit
    for bit without its ``(S, D, H, W')`` temporary.
    """
    if g_f.dtype != np.complex64 or x_f.dtype != np.complex64:
        return np.sum(np.conj(g_f)[None] * x_f, axis=1)
    out = np.empty((x_f.shape[0], *x_f.shape[2:]), np.complex64)
    _correlate(np.ascontiguousarray(g_f), np.ascontiguousarray(x_f), out)
    return out


@kernel
def _correlate(g_f, x_f, out):  # pragma: no cover - compiled
    n_s, n_d = x_f.shape[0], x_f.shape[1]
    n_k = x_f.shape[2] * x_f.shape[3]
    g = g_f.reshape(n_d, n_k)
    o = out.reshape(n_s, n_k)
    re = np.empty(n_k, np.float32)
    im = np.empty(n_k, np.float32)
    for s in range(n_s):
        x = x_f[s].reshape(n_d, n_k)
        for d in range(n_d):
            for k in range(n_k):
                gr, gi = g[d, k].real, -g[d, k].imag  # conj(ĝ)
                xr, xi = x[d, k].real, x[d, k].imag
                pr = fma32(gr, xr, -(gi * xi))
                pi = fma32(gr, xi, gi * xr)
                if d == 0:
                    re[k] = pr
                    im[k] = pi
                else:
                    re[k] = re[k] + pr
                    im[k] = im[k] + pi
        for k in range(n_k):
            o[s, k] = complex(re[k], im[k])


def gaussian_label(shape: tuple[int, int], sigma: float) -> np.ndarray:
    """The desired correlation output y: a 2-D Gaussian with its peak at the origin, (H, W)."""
    rs = signed_indices(shape[0]).astype(np.float64)
    cs = signed_indices(shape[1]).astype(np.float64)
    d2 = rs[:, None] ** 2 + cs[None, :] ** 2
    return np.exp(-0.5 * d2 / sigma**2).astype(np.float32)


def spatial_response(spectrum: np.ndarray, shape: tuple[int, int], hermitian: bool) -> np.ndarray:
    """The real spatial map of a response spectrum, as MATLAB's ``ifft2(X, 'symmetric')`` gives it.

    ``hermitian=True``: ``spectrum`` is a half spectrum from ``rfft2`` (..., H, W//2+1) of a map
    that is real by construction (the paper's formulation), so this is an exact inverse.

    ``hermitian=False``: ``spectrum`` is a full (..., H, W) spectrum that need not be conjugate
    symmetric (the release's formulation). MATLAB ignores the redundant half: for a single 2-D map
    it keeps the first half along the column axis, for a stack of maps (ARCF-H's scales, 3-D) it
    keeps the first half along the row axis. Reproducing that choice is what makes the release's
    boxes reproducible (see the reference notes).
    """
    if hermitian:
        return sfft.irfft2(spectrum, s=shape)
    if spectrum.ndim == 2:
        return sfft.irfft2(spectrum, s=shape)
    return sfft.irfftn(spectrum, s=(shape[1], shape[0]), axes=(-1, -2))


def shift_spectrum(
    x_f: np.ndarray, shift: tuple[float, float], shape: tuple[int, int]
) -> np.ndarray:
    """The spectra ``(..., H, W')`` of maps moved by ``shift`` = (rows, cols) cells, so that
    what was at ``shift`` from the origin comes to the origin: ``x(n + shift)``, by the shift
    theorem, ``X(k) exp(2 pi i k shift / N)`` (ECO's ``shift_sample``).

    ``W'`` is ``W`` (full spectra) or ``W // 2 + 1`` (half spectra of real maps). The move is
    circular: what leaves one border comes in at the other.
    """
    h, w = shape
    ky = signed_indices(h).astype(np.float64)
    kx = signed_indices(w).astype(np.float64)[: x_f.shape[-1]]
    ramp = np.exp(2j * np.pi * (ky[:, None] * (shift[0] / h) + kx[None, :] * (shift[1] / w)))
    return x_f * ramp.astype(x_f.dtype)


def first_argmax_colmajor(m: np.ndarray) -> tuple[int, int]:
    """(row, col) of the maximum of a 2-D map, ties broken as MATLAB's column-major ``find``."""
    flat = np.argmax(m.T)
    col, row = np.unravel_index(flat, (m.shape[1], m.shape[0]))
    return int(row), int(col)


def newton_peak(
    response: np.ndarray, spectrum: np.ndarray, iterations: int
) -> tuple[float, float, int, float]:
    """Sub-cell peak of a stack of response maps by Newton's method on their Fourier series.

    ``response``: real (S, H, W) maps, used for the integer starting point of each map.
    ``spectrum``: full complex (S, H, W) DFTs of the maps (fft2 of ``response`` in the paper's
    formulation; the raw, possibly non-Hermitian, spectrum in the release's).

    The series f(y, x) = 1/(HW) sum_k R[k] exp(i (ky y + kx x)) is maximised jointly in (y, x) from
    each map's integer peak (BACF's ``resp_newton``); a map whose refined value did not increase
    keeps its integer peak. Returns (disp_row, disp_col, best_scale_index, peak_value) with the
    displacements in cells, wrapped into [-n/2, n/2).
    """
    s, h, w = response.shape
    ky = signed_indices(h).astype(np.float64)
    kx = signed_indices(w).astype(np.float64)
    rf = spectrum.astype(np.complex128, copy=False)

    # integer start per map: MATLAB max over rows, then over columns (first occurrence)
    rows = np.empty(s, dtype=np.int64)
    cols = np.empty(s, dtype=np.int64)
    init_val = np.empty(s, dtype=np.float64)
    for i in range(s):
        rows[i], cols[i] = first_argmax_colmajor(response[i])
        init_val[i] = response[i, rows[i], cols[i]]
    hy, hx = (h - 1) // 2, (w - 1) // 2
    trans_row = np.mod(rows + hy, h) - hy
    trans_col = np.mod(cols + hx, w) - hx
    init_y = 2 * np.pi * trans_row / h
    init_x = 2 * np.pi * trans_col / w
    py, px = init_y.copy(), init_x.copy()

    # Powers of the frequencies, stacked so one pair of batched matmuls per iteration gives every
    # term: m[a, b] = sum_k ky^a exp(i ky y) R[k] kx^b exp(i kx x), a, b in 0..2.
    ky_pow = np.stack([np.ones_like(ky), ky, ky * ky])  # (3, H)
    kx_pow = np.stack([np.ones_like(kx), kx, kx * kx])  # (3, W)

    def series(py: np.ndarray, px: np.ndarray) -> np.ndarray:
        ey = np.exp(1j * py[:, None] * ky[None, :])[:, None, :] * ky_pow[None]  # (S, 3, H)
        ex = np.exp(1j * px[:, None] * kx[None, :])[:, :, None] * kx_pow.T[None]  # (S, W, 3)
        return ey @ (rf @ ex)  # (S, 3, 3)

    for _ in range(iterations):
        m = series(py, px)
        ival = 1j * m[:, 0, 0]
        grad_y = -np.imag(m[:, 1, 0])
        grad_x = -np.imag(m[:, 0, 1])
        h_yy = np.real(-m[:, 2, 0] + ival)
        h_xx = np.real(-m[:, 0, 2] + ival)
        h_xy = np.real(-m[:, 1, 1])
        det = h_yy * h_xx - h_xy * h_xy
        with np.errstate(divide="ignore", invalid="ignore"):
            new_y = py - (h_xx * grad_y - h_xy * grad_x) / det
            new_x = px - (h_yy * grad_x - h_xy * grad_y) / det
        ok = np.isfinite(new_y) & np.isfinite(new_x)
        step = np.max(np.abs(np.where(ok, new_y - py, 0)) + np.abs(np.where(ok, new_x - px, 0)))
        py = np.where(ok, new_y, py)
        px = np.where(ok, new_x, px)
        if step < 1e-10:  # converged (quadratically): further iterations are a fixed point
            break

    val = np.real(series(py, px)[:, 0, 0]) / (h * w)
    worse = ~(val >= init_val)  # also catches NaN
    val = np.where(worse, init_val, val)
    py = np.where(worse, init_y, py)
    px = np.where(worse, init_x, px)
    best = int(np.argmax(val))
    disp_row = (np.mod(py[best] + np.pi, 2 * np.pi) - np.pi) / (2 * np.pi) * h
    disp_col = (np.mod(px[best] + np.pi, 2 * np.pi) - np.pi) / (2 * np.pi) * w
    return float(disp_row), float(disp_col), best, float(val[best])


def peak_to_sidelobe(response: np.ndarray, exclude_radius: int) -> float:
    """Peak-to-sidelobe ratio of a 2-D map: (peak - mean) / std of the map outside the main lobe.

    The main lobe is a (2r+1)^2 window around the peak, taken circularly since the maps are
    periodic. A flat sidelobe (std 0) gives 0 rather than infinity, so the score stays finite.
    """
    h, w = response.shape
    r0, c0 = first_argmax_colmajor(response)
    peak = float(response[r0, c0])
    mask = np.ones((h, w), dtype=bool)
    rr = np.arange(r0 - exclude_radius, r0 + exclude_radius + 1) % h
    cc = np.arange(c0 - exclude_radius, c0 + exclude_radius + 1) % w
    mask[np.ix_(rr, cc)] = False
    side = response[mask]
    if side.size < 2:
        return 0.0
    std = float(side.std())
    return 0.0 if std <= 1e-12 else (peak - float(side.mean())) / std
