"""The ADMM solver minimises the paper's objective (Eq. 3/5) over cropped filters; the
aberrance measure (Eq. 2) and the release's aberrance target that feed it."""

from __future__ import annotations

import numpy as np
import pytest

from arcf.aberrance import map_difference, release_target, symmetric_half
from arcf.admm import Crop, objective, solve_filter
from arcf.fourier import full_spectrum, gaussian_label, shift_spectrum


def _problem(seed: int = 0, d: int = 3, n: int = 12, crop: int = 4):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((d, n, n)).astype(np.float64)
    y = gaussian_label((n, n), 1.0).astype(np.float64)
    # a previous response map that is not symmetric, so a wrong conjugation would show
    target = np.roll(gaussian_label((n, n), 1.5), (1, 2), axis=(0, 1)) * 0.6
    target = target + 0.05 * rng.standard_normal((n, n))
    return x, y, target, Crop((n, n), (crop, crop))


def _exact(x, y, target, gamma, lam, crop):
    """Minimiser of the objective by the normal equations over the cropped coefficients."""
    d = x.shape[0]
    rs, cs = crop.slices
    basis = []
    for k in range(d):
        for i in range(rs.start, rs.stop):
            for j in range(cs.start, cs.stop):
                h = np.zeros_like(x)
                h[k, i, j] = 1.0
                basis.append(h)
    xf = np.fft.fft2(x)
    cols = [
        np.real(np.fft.ifft2(np.sum(np.conj(np.fft.fft2(h)) * xf, axis=0))).ravel() for h in basis
    ]
    a = np.stack(cols, axis=1)
    tgt = y.ravel() + gamma * (target.ravel() if target is not None else 0)
    lhs = (1 + gamma) * a.T @ a + lam * np.eye(a.shape[1])
    coef = np.linalg.solve(lhs, a.T @ tgt)
    return sum(c * h for c, h in zip(coef, basis, strict=True))


def _run(x, y, target, gamma, crop, hermitian, iterations, **kw):
    fwd = np.fft.rfft2 if hermitian else np.fft.fft2
    g_f, h_f = solve_filter(
        fwd(x),
        fwd(y),
        None if target is None else fwd(target),
        gamma=gamma,
        admm_lambda=0.01,
        iterations=iterations,
        crop=crop,
        hermitian=hermitian,
        **kw,
    )
    shape = x.shape[-2:]
    h = np.fft.irfft2(h_f, s=shape) if hermitian else np.real(np.fft.ifft2(h_f))
    return g_f, h


@pytest.mark.parametrize("hermitian", [True, False])
@pytest.mark.parametrize("gamma", [0.0, 0.71])
def test_admm_lowers_the_objective_and_reaches_the_optimum(hermitian, gamma):
    x, y, target, crop = _problem()
    tgt = target if gamma else None
    e_zero = objective(np.zeros_like(x), x, y, tgt, gamma, 0.01)
    _, h5 = _run(x, y, tgt, gamma, crop, hermitian, 5)
    e5 = objective(h5, x, y, tgt, gamma, 0.01)
    _, h1 = _run(x, y, tgt, gamma, crop, hermitian, 1)
    e1 = objective(h1, x, y, tgt, gamma, 0.01)
    # the release's fast schedule (mu x10 per iteration) lowers the objective at every step
    assert e5 < e1 < 0.9 * e_zero

    # with a slower penalty schedule ADMM converges to the constrained minimiser
    _, h = _run(x, y, tgt, gamma, crop, hermitian, 300, mu_scale_step=1.05, mu_max=50.0)
    h_star = _exact(x, y, tgt, gamma, 0.01, crop)
    e_star = objective(h_star, x, y, tgt, gamma, 0.01)
    e_admm = objective(h, x, y, tgt, gamma, 0.01)
    assert e_admm == pytest.approx(e_star, rel=1e-3)
    assert np.allclose(h, h_star, atol=1e-3 * np.abs(h_star).max())
    # the filter lives in the crop window only (BACF's B)
    outside = crop.apply(h) - h
    assert np.abs(outside).max() < 1e-9


def test_aberrance_term_pulls_the_response_towards_the_target():
    x, y, target, crop = _problem(seed=3)
    _, h0 = _run(x, y, None, 0.0, crop, True, 300, mu_scale_step=1.05, mu_max=50.0)
    _, h1 = _run(x, y, target, 3.0, crop, True, 300, mu_scale_step=1.05, mu_max=50.0)

    def response(h):
        return np.real(np.fft.ifft2(np.sum(np.conj(np.fft.fft2(h)) * np.fft.fft2(x), axis=0)))

    d0 = np.linalg.norm(response(h0) - target)
    d1 = np.linalg.norm(response(h1) - target)
    assert d1 < d0


def test_half_and_full_spectrum_agree_for_real_targets():
    x, y, target, crop = _problem(seed=5)
    g_half, _ = _run(x, y, target, 0.71, crop, True, 5)
    g_full, _ = _run(x, y, target, 0.71, crop, False, 5)
    assert np.allclose(g_full[..., : g_half.shape[-1]], g_half, atol=1e-8)


@pytest.mark.parametrize("n", [12, 13])
def test_symmetric_half_is_what_a_real_inverse_keeps(n):
    """``symmetric_half`` of any spectrum is the half spectrum of the real part of its inverse."""
    rng = np.random.default_rng(n)
    x = rng.standard_normal((n, n + 3)) + 1j * rng.standard_normal((n, n + 3))
    half = symmetric_half(x)
    assert half.shape == (n, (n + 3) // 2 + 1)
    np.testing.assert_allclose(half, np.fft.rfft2(np.real(np.fft.ifft2(x))), atol=1e-12)


@pytest.mark.parametrize("n", [12, 13])
@pytest.mark.parametrize("iterations", [1, 2, 5])
def test_release_target_in_half_spectra_solves_for_the_symmetric_part(n, iterations):
    """Why ``spectra="half"`` may drop the release target's anti-symmetric part: ADMM never
    mixes it into the conjugate-symmetric part of the filter, so the half-spectrum solve with
    ``symmetric_half(target)`` is the symmetric part of the release's full-spectrum solve, which
    is all that the real part of a response reads."""
    x, y, target, _ = _problem(seed=n, n=n)
    crop = Crop((n, n), (4, 5))
    spectrum_like = release_target(target).astype(np.complex128)  # a real map used as a spectrum
    g_full, h_full = solve_filter(np.fft.fft2(x), np.fft.fft2(y), spectrum_like, gamma=0.71,
                                  admm_lambda=0.01, iterations=iterations, crop=crop,
                                  hermitian=False)
    g_half, h_half = solve_filter(np.fft.rfft2(x), np.fft.rfft2(y),
                                  symmetric_half(spectrum_like), gamma=0.71, admm_lambda=0.01,
                                  iterations=iterations, crop=crop, hermitian=True)
    # the release's filter is not conjugate symmetric, so the two layouts do differ ...
    assert np.abs(g_full[..., : g_half.shape[-1]] - g_half).max() > 1e-3 * np.abs(g_half).max()
    # ... by exactly its anti-symmetric part
    for d in range(x.shape[0]):
        np.testing.assert_allclose(symmetric_half(g_full[d]), g_half[d], atol=1e-9)
        np.testing.assert_allclose(symmetric_half(h_full[d]), h_half[d], atol=1e-9)


def test_map_difference_paper_and_release_forms():
    """(Frobenius norm of D, largest singular value of |D|) with D = M_prev[psi] - M_curr: the
    release's ``norm(abs(D))`` is not the signed difference's spectral norm."""
    m_curr = np.array([[0.5, 0.2], [0.1, 0.3]])
    d = np.array([[1.0, -1.0], [1.0, 1.0]])  # ||D||_2 = sqrt(2), || |D| ||_2 = 2, ||D||_F = 2
    frob, release = map_difference(m_curr + d, m_curr)
    assert frob == pytest.approx(2.0) and release == pytest.approx(2.0)
    assert np.linalg.norm(d, 2) == pytest.approx(np.sqrt(2.0))  # the signed form: lower
    rng = np.random.default_rng(4)
    a, b = rng.standard_normal((2, 9, 11))
    frob, release = map_difference(a, b)
    assert frob == pytest.approx(np.linalg.norm(a - b))
    assert release == pytest.approx(np.linalg.norm(np.abs(a - b), 2))
    assert release > np.linalg.norm(a - b, 2) * 1.05 and release <= frob * (1 + 1e-12)
    assert all(np.isnan(map_difference(np.full((2, 2), np.nan), m_curr)))


def test_release_target_is_the_shifted_map_times_the_number_of_cells():
    """The release uses the spatial, fftshifted map M_prev[psi] as if it were a spectrum and
    does not divide it by T = H*W as it does the label: solve_filter divides every target by T,
    so the target handed to it is T * M_prev[psi], with no further shift."""
    m = np.random.default_rng(6).random((5, 7))
    before = m.copy()
    target = release_target(m)
    np.testing.assert_array_equal(target, m * 35.0)
    np.testing.assert_array_equal(m, before)  # the input is not modified


@pytest.mark.parametrize("hermitian", [True, False])
@pytest.mark.parametrize("gamma", [0.0, 0.71])
@pytest.mark.parametrize("iterations", [1, 2, 5])
def test_compiled_iterations_equal_numpy_bit_for_bit(hermitian, gamma, iterations):
    """The compiled path (g-step with μĝ + ζ̂, the window-only scaling of the h-step, no
    multiplier update after the last iteration) gives NumPy's float32 results to the bit.
    NumPy's lines run when an input is not contiguous, so the same complex64 problem is solved
    both ways."""
    import scipy.fft as sfft

    rng = np.random.default_rng(7)
    d, n = 5, 20
    fwd = sfft.rfft2 if hermitian else sfft.fft2
    x = fwd(rng.standard_normal((d, n, n)).astype(np.float32))
    y = fwd(gaussian_label((n, n), 1.5))
    target = fwd(np.roll(gaussian_label((n, n), 2.0), (2, 1), axis=(0, 1)).astype(np.float32))
    if not hermitian:  # the release's non-symmetric target
        target = target + 0.1 * fwd(rng.standard_normal((n, n)).astype(np.float32))
    x, y, target = (a.astype(np.complex64) for a in (x, y, target))
    strided = np.zeros((d, n, 2 * x.shape[-1]), np.complex64)[..., ::2]
    strided[...] = x
    assert not strided.flags.c_contiguous
    kw = dict(gamma=gamma, admm_lambda=0.01, iterations=iterations, crop=Crop((n, n), (7, 5)),
              hermitian=hermitian)
    compiled = solve_filter(x, y, target, **kw)
    plain = solve_filter(strided, y, target, **kw)
    for a, b in zip(compiled, plain, strict=True):
        assert a.dtype == b.dtype == np.complex64
        np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


@pytest.mark.parametrize("hermitian", [True, False])
@pytest.mark.parametrize(("d", "h", "w", "sh", "sw"), [
    (42, 50, 50, 20, 22), (31, 50, 50, 16, 12), (5, 49, 51, 7, 9), (4, 37, 26, 5, 3),
    (3, 20, 20, 1, 20), (2, 9, 8, 9, 1),
])
def test_pruned_h_step_equals_the_2d_transforms(hermitian, d, h, w, sh, sw):
    """The h-step's pass-by-pass transforms, each only where the crop lets values through, give
    the 2-D transforms' ĥ to the bit (same passes, same order, same normalisation)."""
    import scipy.fft as sfft

    from arcf.admm import h_step

    rng = np.random.default_rng(d * h + w)
    crop = Crop((h, w), (sh, sw))
    real = rng.standard_normal((d, h, w)).astype(np.float32)
    if hermitian:
        spectrum = (sfft.rfft2(real) * 3.7).astype(np.complex64)
        expected = sfft.rfft2(crop.apply(sfft.irfft2(spectrum, s=(h, w)), 0.9993))
    else:
        imag = rng.standard_normal((d, h, w)).astype(np.float32)
        spectrum = (sfft.fft2(real) + 0.5j * sfft.fft2(imag)).astype(np.complex64)
        expected = sfft.fft2(crop.apply(sfft.ifft2(spectrum), 0.9993))
    got = h_step(spectrum, crop, 0.9993, hermitian)
    assert got.dtype == np.complex64
    np.testing.assert_array_equal(got.view(np.uint32), expected.view(np.uint32))


@pytest.mark.parametrize("shape", [(12, 12), (13, 10)])
@pytest.mark.parametrize("half", [True, False])
def test_shift_spectrum_moves_maps_circularly(shape, half):
    """``shift_spectrum`` by whole cells is ``np.roll`` in space; by fractions it interpolates
    a band-limited map between them (the DFT shift theorem)."""
    fwd = np.fft.rfft2 if half else np.fft.fft2
    x = np.random.default_rng(3).standard_normal((2, *shape))
    moved = shift_spectrum(fwd(x), (2.0, -3.0), shape)
    np.testing.assert_allclose(moved, fwd(np.roll(x, (-2, 3), axis=(-2, -1))), atol=1e-9)
    # half a cell twice is one cell
    h, w = shape
    smooth = np.cos(2 * np.pi * np.arange(w) / w)[None, :] * np.ones((h, 1))
    twice = shift_spectrum(shift_spectrum(np.fft.fft2(smooth), (0, 0.5), shape), (0, 0.5), shape)
    np.testing.assert_allclose(np.real(np.fft.ifft2(twice)), np.roll(smooth, -1, axis=1),
                               atol=1e-9)


@pytest.mark.parametrize("shape", [(12, 12), (13, 10), (9, 7)])
def test_full_spectrum_completes_a_half_spectrum(shape):
    x = np.random.default_rng(8).standard_normal((3, *shape))
    np.testing.assert_allclose(full_spectrum(np.fft.rfft2(x), shape[1]), np.fft.fft2(x),
                               atol=1e-12)


@pytest.mark.parametrize(("d", "h", "w"), [(31, 50, 26), (42, 50, 50), (1, 7, 4), (5, 1, 1)])
def test_power_sum_is_einsums_real_part_bit_for_bit(d, h, w):
    """Σ_d |x̂_d|² compiled: the same float32 bits as NumPy's ``einsum`` of conj(x̂) x̂, over
    values spanning six orders of magnitude (where a different summation order shows)."""
    from arcf.admm import _power_sum

    rng = np.random.default_rng(d * h)
    scale = 10.0 ** rng.uniform(-3, 3, (d, h, w))
    x = ((rng.standard_normal((d, h, w)) + 1j * rng.standard_normal((d, h, w))) * scale)
    x = x.astype(np.complex64)
    expected = np.einsum("dhw,dhw->hw", np.conj(x), x).real
    out = np.full((h, w), np.nan, np.float32)
    _power_sum(x, out)
    np.testing.assert_array_equal(out.view(np.uint32), expected.view(np.uint32))


@pytest.mark.parametrize("shape", [(50, 50), (50, 49), (7, 8), (1, 1)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_symmetric_half_of_a_real_map_is_the_numpy_formula_bit_for_bit(shape, dtype):
    """The compiled path for real maps (the release's target) gives what the general
    formula gives, ``0.5 (T(n) + conj(T(-n)))`` on the kept half, to the bit and in the same
    precision."""
    t = (np.random.default_rng(3).standard_normal(shape) * 1e3).astype(dtype)
    h, w = shape
    mirrored = np.conj(t[np.ix_(-np.arange(h) % h, -np.arange(w // 2 + 1) % w)])
    expected = 0.5 * (t[:, : w // 2 + 1] + mirrored)
    got = symmetric_half(t)
    assert got.dtype == expected.dtype == dtype
    np.testing.assert_array_equal(got.view(np.uint8), expected.view(np.uint8))


@pytest.mark.parametrize("shape", [(5, 50, 50), (50, 49), (2, 7, 8), (1, 1, 1)])
def test_full_spectrum_is_a_copy_and_a_mirrored_conjugate_bit_for_bit(shape):
    """The compiled completion, into complex64 or straight into complex128 (Newton's input),
    holds exactly the input's values and their mirrored conjugates."""
    x = np.random.default_rng(4).standard_normal(shape).astype(np.float32)
    half = np.fft.rfft2(x).astype(np.complex64)
    h, w = shape[-2:]
    cols = np.arange(w // 2 + 1, w)
    expected = np.empty((*half.shape[:-1], w), np.complex64)
    expected[..., : w // 2 + 1] = half
    expected[..., w // 2 + 1:] = np.conj(half[..., -np.arange(h) % h, :][..., w - cols])
    for dtype in (None, np.complex128):
        got = full_spectrum(half, w, dtype)
        assert got.dtype == (dtype or np.complex64)
        np.testing.assert_array_equal(got.view(np.uint8),
                                      expected.astype(got.dtype).view(np.uint8))
