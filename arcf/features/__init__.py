"""Hand-crafted features of the ARCF trackers: fHOG, grayscale and Color Names."""

from __future__ import annotations

import time


def warm_up() -> float:
    """Compile the features' Numba kernels, or load them from Numba's cache; returns seconds.

    Why: each kernel is compiled on its first call, about 5.6 s for all of them on a machine
    that has not cached them yet (0.2 s to load them once cached, in ``__pycache__`` beside
    the sources, else in ``$NUMBA_CACHE_DIR`` or the user's cache directory). A service calls
    this when a worker starts, so that the first frame of the first stream does not pay.
    """
    import numpy as np

    from .fhog import fhog
    from .pixel import cell_average
    from .resize import resize_area

    t0 = time.perf_counter()
    patch = np.arange(9 * 9 * 3, dtype=np.uint8).reshape(1, 9, 9, 3)
    fhog(patch, 4, arithmetic="release")
    cell_average(patch.astype(np.float32), 4)
    resize_area(patch[0], (4, 4))
    return time.perf_counter() - t0
