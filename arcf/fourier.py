"""Fourier-domain helpers shared by the trackers: windows, labels, inverse FFTs, peak search.

Conventions: spatial maps are (..., H, W) with the origin at index (0, 0) (circularly shifted, as
the release stores its labels); "signed" indices run 0, 1, ..., ceil((n-1)/2), -floor((n-1)/2),
..., -1 as MATLAB's ``circshift(-floor((n-1)/2):ceil((n-1)/2), -floor((n-1)/2))`` produces.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.fft as sfft

from ._jit import fma32, kernel


@lru_cache(maxsize=64)
def signed_indices(n: int) -> np.ndarray:
    """Integer offsets of the DFT grid in storage order: 0..ceil((n-1)/2), then negatives.

    Read-only and cached: Newton's peak search asks for them twice a frame (6 µs each).
    """
    half = (n - 1) // 2
    out = np.roll(np.arange(-half, n - half), -half)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=64)
def signed_frequencies(n: int) -> np.ndarray:
    """``signed_indices(n)`` as float64 (read-only, cached): the wave numbers of the series."""
    out = signed_indices(n).astype(np.float64)
    out.setflags(write=False)
    return out


def roll2d(m: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """``np.roll(m, (rows, cols), axis=(0, 1))`` of a 2-D map, in one compiled pass (np.roll
    makes four slice copies and cost 8-10 µs a call on the trackers' 50x50 maps, twice a
    frame); a copy, element for element."""
    out = np.empty_like(m)
    _roll2d(np.ascontiguousarray(m), rows % m.shape[0] if m.shape[0] else 0,
            cols % m.shape[1] if m.shape[1] else 0, out)
    return out


def fftshift2d(m: np.ndarray) -> np.ndarray:
    """``scipy.fft.fftshift`` of a 2-D map (``roll2d`` by half the size)."""
    return roll2d(m, m.shape[0] // 2, m.shape[1] // 2)


@kernel
def _roll2d(m, rows, cols, out):  # pragma: no cover - compiled
    h, w = m.shape
    for r in range(h):
        dst = out[(r + rows) % h]
        src = m[r]
        for c in range(w - cols):
            dst[c + cols] = src[c]
        for c in range(w - cols, w):
            dst[c + cols - w] = src[c]


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
    rs = signed_frequencies(shape[0])
    cs = signed_frequencies(shape[1])
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
    boxes reproducible (docs/release.md).
    """
    if hermitian:
        return sfft.irfft2(spectrum, s=shape)
    if spectrum.ndim == 2:
        return sfft.irfft2(spectrum, s=shape)
    return sfft.irfftn(spectrum, s=(shape[1], shape[0]), axes=(-1, -2))


def full_spectrum(half: np.ndarray, width: int, dtype: np.dtype | type | None = None
                  ) -> np.ndarray:
    """The full ``(..., H, width)`` DFT of real maps from their half spectra ``(..., H, width //
    2 + 1)`` (``rfft2``'s layout), the missing columns by conjugate symmetry, X(-k) = X(k)*.

    ``dtype``: of the result (default: the input's), e.g. complex128 for ``newton_peak``,
    which then needs no converted copy.
    """
    h, kept = half.shape[-2:]
    if kept != width // 2 + 1:
        raise ValueError(f"full_spectrum: a half spectrum of width {width} has "
                         f"{width // 2 + 1} columns, got {kept}")
    out = np.empty((*half.shape[:-1], width), half.dtype if dtype is None else dtype)
    if half.dtype.kind == "c" and out.dtype.kind == "c" and half.ndim >= 2:
        flat_half = half.reshape(-1, h, kept)
        if half.dtype != out.dtype:
            flat_half = flat_half.astype(out.dtype)  # exact: complex64 -> complex128
        _complete_spectrum(flat_half, out.reshape(-1, h, width))
        return out
    out[..., :kept] = half
    cols = np.arange(kept, width)
    out[..., kept:] = np.conj(half[..., -np.arange(h) % h, :][..., width - cols])
    return out


@kernel
def _complete_spectrum(half, out):  # pragma: no cover - compiled
    """``full_spectrum`` of ``(N, H, W')`` into ``(N, H, W)``: a copy and a mirrored
    conjugate, in one pass (the fancy-indexed NumPy version made two copies)."""
    n, h, kept = half.shape
    width = out.shape[2]
    for i in range(n):
        for r in range(h):
            mirror = (h - r) % h
            for c in range(kept):
                out[i, r, c] = half[i, r, c]
            for c in range(kept, width):
                out[i, r, c] = np.conj(half[i, mirror, width - c])


def shift_spectrum(
    x_f: np.ndarray, shift: tuple[float, float], shape: tuple[int, int]
) -> np.ndarray:
    """The spectra ``(..., H, W')`` of maps moved by ``shift`` = (rows, cols) cells, so that
    what was at ``shift`` from the origin comes to the origin: ``x(n + shift)``, by the shift
    theorem, ``X(k) exp(2 pi i k shift / N)`` (ECO's ``shift_sample``).

    ``W'`` is ``W`` (full spectra) or ``W // 2 + 1`` (half spectra of real maps). The move is
    circular: what leaves one border comes in at the other. A fractional move of an even-sized
    grid gives the Nyquist row / column a complex phase, which no real map has (an inverse
    ``irfft2`` drops part of it), as in ECO; the trackers' windowed maps carry next to nothing
    there.
    """
    h, w = shape
    ky = signed_frequencies(h)
    kx = signed_frequencies(w)[: x_f.shape[-1]]
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
    ``spectrum``: full complex (S, H, W) DFTs of the maps: the raw, possibly non-Hermitian,
    correlation spectrum in the release's formulation; with half spectra either ``fft2`` of
    ``response`` or the correlation's half spectrum completed by ``full_spectrum``.

    The series f(y, x) = 1/(HW) sum_k R[k] exp(i (ky y + kx x)) is maximised jointly in (y, x) from
    each map's integer peak (BACF's ``resp_newton``); a map whose refined value did not increase
    keeps its integer peak. Returns (disp_row, disp_col, best_scale_index, peak_value) with the
    displacements in cells, wrapped into [-n/2, n/2).
    """
    if iterations < 0:
        raise ValueError(f"newton_peak: iterations must be >= 0, got {iterations}")
    h, w = response.shape[1:]
    ky = signed_frequencies(h)
    kx = signed_frequencies(w)
    rf = spectrum.astype(np.complex128, copy=False)

    # integer start per map: MATLAB max over rows, then over columns (first occurrence)
    rows, cols, init_val = _integer_peaks(response)
    hy, hx = (h - 1) // 2, (w - 1) // 2
    trans_row = np.mod(rows + hy, h) - hy
    trans_col = np.mod(cols + hx, w) - hx
    init_y = 2 * np.pi * trans_row / h
    init_x = 2 * np.pi * trans_col / w
    py, px = init_y.copy(), init_x.copy()

    val = _newton(rf, ky, kx, py, px, iterations) / (h * w)
    worse = ~(val >= init_val)  # also catches NaN
    val = np.where(worse, init_val, val)
    py = np.where(worse, init_y, py)
    px = np.where(worse, init_x, px)
    best = int(np.argmax(val))
    disp_row = (np.mod(py[best] + np.pi, 2 * np.pi) - np.pi) / (2 * np.pi) * h
    disp_col = (np.mod(px[best] + np.pi, 2 * np.pi) - np.pi) / (2 * np.pi) * w
    return float(disp_row), float(disp_col), best, float(val[best])


@kernel
def _integer_peaks(maps):  # pragma: no cover - compiled
    """Each (S, H, W) map's maximum: (rows, cols, values), ties to the first in column-major
    order (``first_argmax_colmajor``); a NaN counts as the maximum where it comes first, as
    ``np.argmax`` counts it."""
    n_s, h, w = maps.shape
    rows = np.zeros(n_s, np.int64)
    cols = np.zeros(n_s, np.int64)
    vals = np.empty(n_s, np.float64)
    for i in range(n_s):
        best = maps[i, 0, 0]
        found_nan = best != best
        for x in range(w):
            for y in range(h):
                v = maps[i, y, x]
                if found_nan:
                    break
                if v != v:
                    best, rows[i], cols[i], found_nan = v, y, x, True
                elif v > best:
                    best, rows[i], cols[i] = v, y, x
            if found_nan:
                break
        vals[i] = best
    return rows, cols, vals


@kernel
def _newton(rf, ky, kx, py, px, iterations):  # pragma: no cover - compiled
    """``newton_peak``'s iterations, in place on ``py`` / ``px`` (S,); returns the series' real
    part at the end points (S,).

    Each step evaluates m[a, b] = sum_k ky^a exp(i ky y) R[k] kx^b exp(i kx x), a, b in 0..2,
    for every map (the gradient and Hessian of the series' real part), and moves every map
    whose Newton step is finite; all maps stop together once the largest step (|dy| + |dx|)
    is below 1e-10, as BACF's ``resp_newton`` iterates them together. Sums run in storage
    order (a BLAS product, the earlier formulation, sums in blocks: positions differ in the
    last bits, ~1e-15 cells on the trackers' maps, far below the whole pixels they round to;
    more where the Hessian is nearly singular, e.g. maps one cell high, where any step is
    rounding noise).
    """
    n_s, h, w = rf.shape
    re = np.ascontiguousarray(rf.real)
    im = np.ascontiguousarray(rf.imag)
    cr = np.empty((3, w))  # C_a[x] = sum_y ky^a exp(i ky y) R[y, x], real and imaginary parts
    ci = np.empty((3, w))
    fr = np.empty((3, w))  # kx^b exp(i kx x), real and imaginary parts
    fi = np.empty((3, w))
    m = np.empty((n_s, 3, 3), np.complex128)
    val = np.empty(n_s)
    converged = False
    for it in range(iterations + 1):
        for s in range(n_s):
            cr[:] = 0.0
            ci[:] = 0.0
            for y in range(h):
                er, ei = math.cos(py[s] * ky[y]), math.sin(py[s] * ky[y])
                k1, k2 = ky[y], ky[y] * ky[y]
                rr, ri = re[s, y], im[s, y]
                for x in range(w):  # elementwise over x: vectorised
                    pr = er * rr[x] - ei * ri[x]
                    pi = er * ri[x] + ei * rr[x]
                    cr[0, x] += pr
                    ci[0, x] += pi
                    cr[1, x] += k1 * pr
                    ci[1, x] += k1 * pi
                    cr[2, x] += k2 * pr
                    ci[2, x] += k2 * pi
            for x in range(w):
                fr[0, x], fi[0, x] = math.cos(px[s] * kx[x]), math.sin(px[s] * kx[x])
                fr[1, x], fi[1, x] = fr[0, x] * kx[x], fi[0, x] * kx[x]
                fr[2, x], fi[2, x] = fr[0, x] * (kx[x] * kx[x]), fi[0, x] * (kx[x] * kx[x])
            for a in range(3):
                for b in range(3):
                    acc_r = 0.0
                    acc_i = 0.0
                    for x in range(w):
                        acc_r += cr[a, x] * fr[b, x] - ci[a, x] * fi[b, x]
                        acc_i += cr[a, x] * fi[b, x] + ci[a, x] * fr[b, x]
                    m[s, a, b] = complex(acc_r, acc_i)
        if converged or it == iterations:
            break  # m now holds the series at the final points
        step = 0.0
        for s in range(n_s):
            grad_y = -m[s, 1, 0].imag
            grad_x = -m[s, 0, 1].imag
            h_yy = -m[s, 2, 0].real - m[s, 0, 0].imag
            h_xx = -m[s, 0, 2].real - m[s, 0, 0].imag
            h_xy = -m[s, 1, 1].real
            det = h_yy * h_xx - h_xy * h_xy
            new_y = py[s] - (h_xx * grad_y - h_xy * grad_x) / det
            new_x = px[s] - (h_yy * grad_x - h_xy * grad_y) / det
            if math.isfinite(new_y) and math.isfinite(new_x):
                step = max(step, abs(new_y - py[s]) + abs(new_x - px[s]))
                py[s] = new_y
                px[s] = new_x
        converged = step < 1e-10  # quadratic convergence: further steps are a fixed point
    for s in range(n_s):
        val[s] = m[s, 0, 0].real
    return val


def peak_to_sidelobe(response: np.ndarray, exclude_radius: int) -> float:
    """Peak-to-sidelobe ratio of a 2-D map: (peak - mean) / std of the map outside the main lobe.

    The main lobe is a (2r+1)^2 window around the peak, taken circularly since the maps are
    periodic. A flat sidelobe (std 0) gives 0 rather than infinity, so the score stays finite.
    Mean and (population) standard deviation are accumulated in float64, in one compiled
    pass each: the NumPy version (a mask, a boolean gather, ``std``) cost 0.1 ms per frame in
    the tracker, as much as Newton's search.
    """
    if response.ndim != 2 or response.size == 0:
        raise ValueError(f"peak_to_sidelobe: expected a non-empty 2-D map, got {response.shape}")
    r0, c0 = first_argmax_colmajor(response)
    return float(_psr(response, r0, c0, exclude_radius))


@kernel
def _psr(m, r0, c0, radius):  # pragma: no cover - compiled
    """``peak_to_sidelobe`` after the peak search: the sidelobe is every value whose row and
    column are not both within ``radius`` (circularly) of ``(r0, c0)``."""
    h, w = m.shape
    near_row = np.zeros(h, np.bool_)
    near_col = np.zeros(w, np.bool_)
    for k in range(-radius, radius + 1):
        near_row[(r0 + k) % h] = True
        near_col[(c0 + k) % w] = True
    count = 0
    total = 0.0
    for y in range(h):
        for x in range(w):
            if not (near_row[y] and near_col[x]):
                count += 1
                total += np.float64(m[y, x])
    if count < 2:
        return 0.0
    mean = total / count
    spread = 0.0
    for y in range(h):
        for x in range(w):
            if not (near_row[y] and near_col[x]):
                d = np.float64(m[y, x]) - mean
                spread += d * d
    std = math.sqrt(spread / count)
    return 0.0 if std <= 1e-12 else (np.float64(m[r0, c0]) - mean) / std
