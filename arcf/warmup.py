"""Compile the library's Numba kernels ahead of the first frame."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["warm_up"]


def warm_up() -> float:
    """Compile the compiled kernels, or load them from Numba's cache; returns seconds.

    Why: each kernel is compiled on its first call, about 6 s for all of them on a machine
    that has not cached them yet (0.2 s to load them once cached, in ``__pycache__`` beside
    the sources, else in ``$NUMBA_CACHE_DIR`` or the user's cache directory). A service calls
    this when a worker starts, so that the first frame of the first stream does not pay.
    """
    from .admm import Crop, solve_filter
    from .features.fhog import fhog
    from .features.patches import pyramid_windows, release_windows
    from .features.pixel import cell_average
    from .features.resize import resize_area
    from .fourier import correlate

    t0 = time.perf_counter()
    patch = np.arange(9 * 9 * 3, dtype=np.uint8).reshape(1, 9, 9, 3)
    fhog(patch, 4, arithmetic="release")
    cell_average(patch.astype(np.float32), 4)
    resize_area(patch[0], (4, 4))
    frame = np.zeros((40, 40, 3), np.uint8)
    pyramid_windows(frame, (20.0, 20.0), [(36, 36)], (8, 8))
    release_windows(frame, (20.0, 20.0), [(36, 36), (30, 30)], (8, 8))
    spectrum = np.ones((2, 4, 4), np.complex64)
    correlate(spectrum, spectrum[None])
    label = np.ones((4, 4), np.complex64)
    for hermitian in (True, False):
        solve_filter(spectrum[..., : 3 if hermitian else 4], label[:, : 3 if hermitian else 4],
                     None, gamma=0.0, admm_lambda=0.01, iterations=1,
                     crop=Crop((4, 4), (2, 2)), hermitian=hermitian)
    return time.perf_counter() - t0
