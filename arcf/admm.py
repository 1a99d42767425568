"""The ADMM solver of the paper (Section 4.3): train the filter of one frame.

Symbols, as in the paper and the release:

- ``x̂`` (``model_xf``): the running appearance model in the Fourier domain, (D, H, W') complex.
- ``ŷ`` (``yf``): the DFT of the Gaussian label, (H, W').
- ``M̂ˢ`` (``target_f``): the aberrance target, the previous response map aligned by the shift
  ψ_{p,q}, in the same spectral layout as ``ŷ`` (see :mod:`arcf.aberrance`).
- ``ĝ``: the filter in the Fourier domain (the ADMM auxiliary variable); used for detection.
- ``h`` (``w`` in the paper): the spatial filter, constrained by BACF's cropping matrix B to a
  target-sized window; ``ĥ`` its DFT.
- ``ζ̂`` (``l_f`` in the release): the Lagrange multiplier; ``μ`` the penalty.
- ``T`` = H·W, the number of cells of the feature grid.

W' is W for a full spectrum (``hermitian=False``, the release's formulation, whose filter is not
conjugate symmetric) or W//2+1 for a half spectrum of real maps (``hermitian=True``, the paper's,
which halves the work).

The g-step minimises, per frequency n (Parseval, 1/T scaling as in BACF's release)::

    1/(2T) (|ŷ(n) - ĝ(n)ᴴ x̂(n)|² + γ |M̂ˢ(n) - ĝ(n)ᴴ x̂(n)|²) + Re ζ̂ᴴ(ĝ - ĥ) + μ/2 |ĝ - ĥ|²

The two data terms merge into one with target ỹ = ŷ + γ·conj(M̂ˢ) and weight (1+γ), so the
rank-one system (x̂ x̂ᴴ + Tμ/(1+γ) I) ĝ = ... is solved in closed form with Sherman–Morrison
(the paper's Eq. 14–15). With γ = 0 this is exactly BACF's g-step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from ._jit import fma32, kernel


@dataclass(frozen=True)
class Crop:
    """BACF's cropping matrix B: a target-sized window of the spatial filter, centred in the grid.

    The window starts at ``n//2 - s//2`` along each axis, as the release's
    ``get_subwindow_no_window(h, floor(use_sz/2), small_filter_sz)`` places it.
    """

    grid: tuple[int, int]
    size: tuple[int, int]

    @property
    def slices(self) -> tuple[slice, slice]:
        (gh, gw), (sh, sw) = self.grid, self.size
        r0, c0 = gh // 2 - sh // 2, gw // 2 - sw // 2
        return slice(r0, r0 + sh), slice(c0, c0 + sw)

    def apply(self, h: np.ndarray, scale: float | None = None) -> np.ndarray:
        """Zero the filter outside the window (``B^T B h``), on (..., H, W) maps; ``scale``
        multiplies what is kept (as ``h *= scale`` would, bit for bit, without touching the
        part that is thrown away)."""
        out = np.zeros_like(h)
        rs, cs = self.slices
        if scale is None:
            out[..., rs, cs] = h[..., rs, cs]
        else:
            np.multiply(h[..., rs, cs], scale, out=out[..., rs, cs])
        return out


def solve_filter(
    model_xf: np.ndarray,
    yf: np.ndarray,
    target_f: np.ndarray | None,
    *,
    gamma: float,
    admm_lambda: float,
    iterations: int,
    crop: Crop,
    hermitian: bool,
    mu_init: float = 1.0,
    mu_scale_step: float = 10.0,
    mu_max: float = 1e4,
) -> tuple[np.ndarray, np.ndarray]:
    """Run ADMM from ĝ = ĥ = ζ̂ = 0, μ = μ0 (as the release does every frame).

    Returns (ĝ, ĥ), both shaped like ``model_xf``. ``target_f`` None means no aberrance target
    (first frame, or γ = 0).
    """
    shape = crop.grid
    t = float(shape[0] * shape[1])
    x = model_xf
    if x.dtype == np.complex64 and x.flags.c_contiguous:
        xc = None  # only the NumPy g-step below reads it
        s_xx = np.empty(x.shape[1:], np.float32)
        _power_sum(x, s_xx)
    else:
        xc = np.conj(x)
        s_xx = np.ascontiguousarray(np.einsum("dhw,dhw->hw", xc, x).real)  # Σ_d |x̂_d|², (H, W')
    y_tilde = yf if target_f is None or gamma == 0 else yf + gamma * np.conj(target_f)
    x_y = x * y_tilde  # x̂ ỹ, (D, H, W')
    sxx_y = s_xx * y_tilde
    # The compiled g-step (NumPy's arithmetic, bit for bit) takes the usual complex64 arrays.
    fused = x.dtype == x_y.dtype == sxx_y.dtype == np.complex64 and all(
        a.flags.c_contiguous for a in (x, x_y, sxx_y, s_xx))
    if not fused and xc is None:
        xc = np.conj(x)
    g_f = np.empty_like(x) if fused else np.zeros_like(x)  # the g-step writes all of it
    h_f = np.zeros_like(x)
    l_f = np.zeros_like(x)
    weighted = np.empty_like(x) if fused else None
    mu = mu_init
    scale = 1.0 + gamma
    for i in range(iterations):
        if fused:
            # The same float32 operations as the NumPy lines below, in one pass (_g_step),
            # which also writes μĝ + ζ̂ for the h-step.
            _g_step(
                x, x_y, sxx_y, s_xx, l_f, h_f, np.float32(t * mu / scale),
                np.float32(1) / np.float32(t * mu), np.float32(1) / np.float32(mu),
                np.float32(1.0 / (t * mu)), np.float32(1.0 / mu), np.float32(mu), g_f, weighted,
            )
            assert weighted is not None  # allocated when fused
            spectrum = weighted
        else:
            # g-step: closed form per frequency (Sherman–Morrison)
            assert xc is not None  # conjugated above when not fused
            b = s_xx + t * mu / scale
            s_lx = np.einsum("dhw,dhw->hw", xc, l_f)
            s_hx = np.einsum("dhw,dhw->hw", xc, h_f)
            coef = (sxx_y / (t * mu) - s_lx / mu + s_hx) / b  # (H, W')
            g_f = x_y * (1.0 / (t * mu))
            g_f -= l_f * (1.0 / mu)
            g_f += h_f
            g_f -= x * coef
            spectrum = mu * g_f + l_f
        # h-step: closed form in the spatial domain, then BACF's crop
        h_f = h_step(spectrum, crop, t / (mu * t + admm_lambda), hermitian)
        # Lagrange multiplier and penalty (the last iteration's would never be read)
        if i + 1 < iterations:
            if fused:
                _add_scaled_difference(l_f, np.float32(mu), g_f, h_f)
            else:
                l_f += mu * (g_f - h_f)
        mu = min(mu_scale_step * mu, mu_max)
    return g_f.astype(x.dtype, copy=False), h_f


def h_step(spectrum: np.ndarray, crop: Crop, scale: float, hermitian: bool) -> np.ndarray:
    """``ĥ = F(B^T B (scale · F⁻¹(μĝ + ζ̂)))``: the h-step's closed form and BACF's crop.

    ``spectrum`` is ``μĝ + ζ̂``, ``(D, H, W')``. For complex64 spectra and a crop smaller than
    the grid, the 2-D transforms are run pass by pass, each pass only where the crop lets a
    value through: the inverse's second pass only on the rows the crop keeps, the forward's
    first pass only on the rows (real transforms) or columns (complex) that are not zero. Each
    pass is the one SciPy's 2-D transform runs, in its order and with its normalisation at its
    place (pocketfft scales the last pass of a real inverse, the first of a complex one, by
    ``float32(1 / HW)``), so ĥ is the same to the bit (``tests/arcf/test_admm.py``), in 0.75-0.8 of
    the time on the trackers' crops.
    """
    (height, width), (rows, cols) = crop.grid, crop.slices
    if spectrum.dtype != np.complex64 or crop.size == crop.grid:
        if hermitian:
            h = sfft.irfft2(spectrum, s=crop.grid)
            return sfft.rfft2(crop.apply(h, scale)).astype(spectrum.dtype, copy=False)
        return sfft.fft2(crop.apply(sfft.ifft2(spectrum), scale)).astype(spectrum.dtype,
                                                                          copy=False)
    # pocketfft's norm_fct: 1 / N in long double, rounded to the data's precision
    fct = np.float32(np.longdouble(1) / np.longdouble(height * width))
    n_d = spectrum.shape[0]
    if hermitian:
        passed = sfft.ifft(spectrum, axis=-2, norm="forward")[:, rows, :]
        h = sfft.irfft(passed, n=width, axis=-1, norm="forward")
        h *= fct
        kept = np.zeros_like(h)
        np.multiply(h[:, :, cols], scale, out=kept[:, :, cols])
        out = np.empty_like(spectrum)  # zero outside the kept rows; the last pass in place
        out[:, : rows.start] = 0
        out[:, rows.stop :] = 0
        out[:, rows, :] = sfft.rfft(kept, axis=-1)
        return sfft.fft(out, axis=-2, overwrite_x=True)
    out = np.zeros_like(spectrum)
    passed = sfft.ifft(spectrum, axis=-2, norm="forward")
    passed.view(np.float32)[...] *= fct
    h = sfft.ifft(passed[:, rows, :], axis=-1, norm="forward")
    kept = np.zeros((n_d, height, cols.stop - cols.start), spectrum.dtype)
    np.multiply(h[:, :, cols], scale, out=kept[:, rows, :])
    out[:, :, cols] = sfft.fft(kept, axis=-2)
    return sfft.fft(out, axis=-1, overwrite_x=True)


@kernel
def _g_step(
    x, x_y, sxx_y, s_xx, l_f, h_f, b_shift, inv_tmu, inv_mu, c_tmu, c_mu, mu, g_f, weighted
):  # pragma: no cover - compiled
    """The g-step of one ADMM iteration, per frequency, as ``solve_filter``'s NumPy lines.

    ``b = Σ|x̂|² + Tμ/(1+γ)``; ``coef = (Σ|x̂|² ỹ / (Tμ) - Σ conj(x̂) ζ̂ / μ + Σ conj(x̂) ĥ) /
    b``; ``ĝ = x̂ ỹ / (Tμ) - ζ̂ / μ + ĥ - x̂ coef``. Every operation is NumPy's, in its order
    and rounding: ``einsum``'s plain complex products summed over channels in order, division
    by a real as multiplication by its float32 reciprocal, complex products with one FMA per
    part (``fma32``). Arrays are complex64 ``(D, H, W')``, ``(H, W')`` for the sums; loops run
    over the channel outside and the frequencies inside, which vectorises. Also writes
    ``weighted = μĝ + ζ̂`` (float32, as NumPy rounds it), the h-step's input.
    """
    n_d = x.shape[0]
    n_k = x.shape[1] * x.shape[2]
    xs, xys = x.reshape(n_d, n_k), x_y.reshape(n_d, n_k)
    ls, hs, gs = l_f.reshape(n_d, n_k), h_f.reshape(n_d, n_k), g_f.reshape(n_d, n_k)
    ws = weighted.reshape(n_d, n_k)
    sxy = sxx_y.reshape(n_k)
    sxx = s_xx.reshape(n_k)
    lr = np.zeros(n_k, np.float32)
    li = np.zeros(n_k, np.float32)
    hr = np.zeros(n_k, np.float32)
    hi = np.zeros(n_k, np.float32)
    for d in range(n_d):
        for k in range(n_k):
            xr, xi = xs[d, k].real, -xs[d, k].imag  # conj(x̂)
            zr, zi = ls[d, k].real, ls[d, k].imag
            lr[k] = lr[k] + (xr * zr - xi * zi)
            li[k] = li[k] + (xr * zi + xi * zr)
            zr, zi = hs[d, k].real, hs[d, k].imag
            hr[k] = hr[k] + (xr * zr - xi * zi)
            hi[k] = hi[k] + (xr * zi + xi * zr)
    cr = np.empty(n_k, np.float32)
    ci = np.empty(n_k, np.float32)
    for k in range(n_k):
        scl = np.float32(1.0) / (sxx[k] + b_shift)
        cr[k] = ((sxy[k].real * inv_tmu - lr[k] * inv_mu) + hr[k]) * scl
        ci[k] = ((sxy[k].imag * inv_tmu - li[k] * inv_mu) + hi[k]) * scl
    for d in range(n_d):
        for k in range(n_k):
            gr = xys[d, k].real * c_tmu
            gi = xys[d, k].imag * c_tmu
            gr = gr - ls[d, k].real * c_mu
            gi = gi - ls[d, k].imag * c_mu
            gr = gr + hs[d, k].real
            gi = gi + hs[d, k].imag
            ar, ai = xs[d, k].real, xs[d, k].imag
            gr = gr - fma32(ar, cr[k], -(ai * ci[k]))
            gi = gi - fma32(ar, ci[k], ai * cr[k])
            gs[d, k] = complex(gr, gi)
            ws[d, k] = complex(mu * gr + ls[d, k].real, mu * gi + ls[d, k].imag)


@kernel
def _power_sum(x, out):  # pragma: no cover - compiled
    """``out = Σ_d |x̂_d|²`` over the channels of a complex64 ``(D, H, W')`` block, as
    ``np.einsum("dhw,dhw->hw", conj(x), x).real`` computes it: each product's real part
    ``xr xr - (-xi) xi`` in float32, summed over the channels in order from 0 (the same bits,
    checked in tests/arcf/test_admm.py; a tenth of einsum's time)."""
    n_d = x.shape[0]
    n_k = x.shape[1] * x.shape[2]
    xs = x.reshape(n_d, n_k)
    acc = out.reshape(n_k)
    acc[:] = 0.0
    for d in range(n_d):
        for k in range(n_k):
            xr = xs[d, k].real
            xi = xs[d, k].imag
            acc[k] = acc[k] + (xr * xr - (-xi) * xi)


@kernel
def _add_scaled_difference(l_f, mu, g_f, h_f):  # pragma: no cover - compiled
    """``ζ̂ += μ (ĝ - ĥ)`` in place (complex64), as NumPy rounds it."""
    flat_l, flat_g, flat_h = l_f.reshape(-1), g_f.reshape(-1), h_f.reshape(-1)
    for k in range(flat_l.size):
        flat_l[k] = complex(flat_l[k].real + mu * (flat_g[k].real - flat_h[k].real),
                            flat_l[k].imag + mu * (flat_g[k].imag - flat_h[k].imag))


def objective(
    h: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    target: np.ndarray | None,
    gamma: float,
    admm_lambda: float,
) -> float:
    """Eq. 3/5 of the paper for a spatial filter ``h`` (D, H, W) on a sample ``x`` (D, H, W).

    E(h) = ½‖y − Σ_d x_d ⋆ h_d‖² + λ/2 ‖h‖² + γ/2 ‖M − Σ_d x_d ⋆ h_d‖², with the correlation
    defined as the trackers apply it (response spectrum Σ conj(ĥ) x̂). Used by the tests to check
    that the solver lowers the objective; not on the tracking path.
    """
    r = np.real(sfft.ifft2(np.sum(np.conj(sfft.fft2(h)) * sfft.fft2(x), axis=0)))
    e = 0.5 * np.sum((y - r) ** 2) + 0.5 * admm_lambda * np.sum(np.abs(h) ** 2)
    if target is not None and gamma:
        e += 0.5 * gamma * np.sum((target - r) ** 2)
    return float(e)
