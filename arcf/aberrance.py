"""The aberrance measure and the aberrance target (paper, Section 4.1, Eq. 2 and 3).

Response maps here are *fftshifted* (peak near the centre), as the release keeps them:
``M_curr = fftshift(response)``. ψ_{p,q} is a circular shift that makes two maps' peaks coincide.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from ._jit import kernel
from .fourier import first_argmax_colmajor, roll2d


def peak_index(m: np.ndarray) -> tuple[int, int]:
    """Integer peak of a map; ties go to the first in MATLAB's column-major order (release)."""
    return first_argmax_colmajor(m)


def shift_to(m: np.ndarray, peak_from: tuple[int, int], peak_to: tuple[int, int]) -> np.ndarray:
    """M[ψ_{p,q}]: circularly shift ``m`` so its peak moves from ``peak_from`` to ``peak_to``."""
    return roll2d(m, peak_to[0] - peak_from[0], peak_to[1] - peak_from[1])


def map_difference(m_prev_shifted: np.ndarray, m_curr: np.ndarray) -> tuple[float, float]:
    """The response-map difference of Eq. 2 in two forms: (paper, release).

    The paper defines the Euclidean (Frobenius) norm of D = M_prev[ψ] − M_curr. The release
    stores MATLAB's ``norm(abs(D))``: the largest singular value of the element-wise absolute
    difference (the signed difference's is 23–42 % lower). The second form is what the published
    ``map_diff`` files, and the paper's Table 2, contain.
    """
    d = (m_prev_shifted - m_curr).astype(np.float64)
    if not np.all(np.isfinite(d)):
        return float("nan"), float("nan")
    frob = float(np.sqrt(np.sum(d * d)))
    spectral = float(np.linalg.norm(np.abs(d), 2)) if d.size else 0.0
    return frob, spectral


def paper_target(m_prev: np.ndarray, peak_prev: tuple[int, int]) -> np.ndarray:
    """The paper's aberrance target as a spatial map in the label's layout (peak at the origin).

    The regulariser of Eq. 3 compares the shifted previous map with the new filter's response on
    the *training* sample, which is centred on the target, so its peak belongs where the label's
    peak is: the origin. Returns the unshifted (origin-layout) map, ready for the DFT, so that
    its spectrum and the label's ŷ are in the same (unnormalised) DFT convention.
    """
    h, w = m_prev.shape
    centred = shift_to(m_prev, peak_prev, (h // 2, w // 2))
    return sfft.ifftshift(centred)


def release_target(m_prev_shifted: np.ndarray) -> np.ndarray:
    """The release's aberrance "spectrum": T · M_prev[ψ], the spatial map used as if a DFT.

    Three facts of the release, each needed for its boxes (docs/release.md, details 3 and 4):
    the map is the spatial previous response, not its DFT (the domain error); it is kept in its
    fftshifted layout (peak near the grid's centre, shifted onto the current peak), not moved to
    the origin; and the release's g-step divides the label term by T = H·W but not the map
    term. :func:`arcf.admm.solve_filter` divides every target by T, hence the factor T here.
    """
    return m_prev_shifted * float(m_prev_shifted.size)


def symmetric_half(spectrum: np.ndarray) -> np.ndarray:
    """The conjugate-symmetric part of a full (H, W) spectrum, (X(n) + conj(X(-n))) / 2, as the
    half spectrum (H, W//2+1) that ``rfft2`` would give for the real map it is the DFT of.

    For the release's target (a real map read as a spectrum) this is (T + flip(T)) / 2, flip
    reversing both axes about index 0 (``TrackerParams.spectra = "half"``).
    """
    h, w = spectrum.shape
    half = w // 2 + 1
    if spectrum.dtype in (np.float32, np.float64):  # the release's target: a real map
        out = np.empty((h, half), spectrum.dtype)
        _symmetric_half_real(spectrum, out)
        return out
    mirrored = np.conj(spectrum[np.ix_(-np.arange(h) % h, -np.arange(half) % w)])  # X(-n)*
    return 0.5 * (spectrum[:, :half] + mirrored)


@kernel
def _symmetric_half_real(t, out):  # pragma: no cover - compiled
    """``symmetric_half`` of a real map, ``0.5 (T(n) + T(-n))`` in its own precision, in one
    pass (the NumPy lines gather a mirrored copy first)."""
    h, w = t.shape
    half = out.shape[1]
    for r in range(h):
        mr = (h - r) % h
        for c in range(half):
            out[r, c] = 0.5 * (t[r, c] + t[mr, (w - c) % w])
