"""Small Fourier-domain helpers the trackers call every frame."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.fft as sfft

from arcf.fourier import fftshift2d, roll2d, signed_frequencies, signed_indices


@pytest.mark.parametrize("shape", [(50, 50), (7, 12), (1, 5), (6, 1)])
def test_roll2d_and_fftshift2d_are_numpys(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(3)
    m = rng.standard_normal(shape).astype(np.float32)
    for rows, cols in ((0, 0), (3, -4), (-60, 61), (shape[0], 2 * shape[1] + 1)):
        np.testing.assert_array_equal(roll2d(m, rows, cols),
                                      np.roll(m, (rows, cols), axis=(0, 1)))
    np.testing.assert_array_equal(fftshift2d(m), sfft.fftshift(m))
    view = rng.standard_normal((3, *shape))[1]  # a view, float64
    np.testing.assert_array_equal(fftshift2d(view), sfft.fftshift(view))


def test_signed_indices_are_cached_read_only() -> None:
    """Cached (Newton asks for them every frame), so nobody may change them in place."""
    for n in (1, 2, 5, 50, 51):
        half = (n - 1) // 2
        expected = np.roll(np.arange(-half, n - half), -half)
        np.testing.assert_array_equal(signed_indices(n), expected)
        np.testing.assert_array_equal(signed_frequencies(n), expected.astype(np.float64))
        assert signed_frequencies(n).dtype == np.float64
        assert signed_indices(n) is signed_indices(n)
        for a in (signed_indices(n), signed_frequencies(n)):
            with pytest.raises(ValueError):
                a[0] = 1
