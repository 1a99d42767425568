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

    def apply(self, h: np.ndarray) -> np.ndarray:
        """Zero the filter outside the window (``B^T B h``), on (..., H, W) maps."""
        out = np.zeros_like(h)
        rs, cs = self.slices
        out[..., rs, cs] = h[..., rs, cs]
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
    xc = np.conj(x)
    s_xx = np.einsum("dhw,dhw->hw", xc, x).real  # Σ_d |x̂_d|², (H, W')
    y_tilde = yf if target_f is None or gamma == 0 else yf + gamma * np.conj(target_f)
    x_y = x * y_tilde  # x̂ ỹ, (D, H, W')
    sxx_y = s_xx * y_tilde
    if hermitian:

        def inv(a: np.ndarray) -> np.ndarray:
            return sfft.irfft2(a, s=shape)

        fwd = sfft.rfft2
    else:
        inv = sfft.ifft2
        fwd = sfft.fft2

    g_f = np.zeros_like(x)
    h_f = np.zeros_like(x)
    l_f = np.zeros_like(x)
    mu = mu_init
    scale = 1.0 + gamma
    for _ in range(iterations):
        # g-step: closed form per frequency (Sherman–Morrison)
        b = s_xx + t * mu / scale
        s_lx = np.einsum("dhw,dhw->hw", xc, l_f)
        s_hx = np.einsum("dhw,dhw->hw", xc, h_f)
        coef = (sxx_y / (t * mu) - s_lx / mu + s_hx) / b  # (H, W')
        g_f = x_y * (1.0 / (t * mu))
        g_f -= l_f * (1.0 / mu)
        g_f += h_f
        g_f -= x * coef
        # h-step: closed form in the spatial domain, then BACF's crop
        h = inv(mu * g_f + l_f)
        h *= t / (mu * t + admm_lambda)
        h_f = fwd(crop.apply(h)).astype(x.dtype, copy=False)
        # Lagrange multiplier and penalty
        l_f += mu * (g_f - h_f)
        mu = min(mu_scale_step * mu, mu_max)
    return g_f.astype(x.dtype, copy=False), h_f


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
