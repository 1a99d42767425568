"""Prepare a process for tracking: compile the Numba kernels, keep freed memory at hand."""

from __future__ import annotations

import ctypes
import logging
import platform
import time

import numpy as np

__all__ = ["warm_up"]

log = logging.getLogger(__name__)

#: glibc's ``mallopt`` parameters (``malloc.h``).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def warm_up() -> float:
    """Compile the compiled kernels, or load them from Numba's cache; returns seconds.

    Why: each kernel is compiled on its first call, about a minute for all of them on a
    machine that has not cached them yet (56 s on one core of the 2-core AMD EPYC; 1.6 s once
    cached, the frames below included; the cache is
    ``__pycache__`` beside the sources, else ``$NUMBA_CACHE_DIR`` or the user's cache
    directory). A service calls this when a worker starts, so that the first frame of the
    first stream does not pay.

    It also tells glibc's allocator to keep freed memory (``keep_freed_memory``), which a
    process that tracks should do.
    """
    keep_freed_memory()
    from .admm import Crop, solve_filter
    from .features.fhog import fhog
    from .features.patches import pyramid_windows, release_windows
    from .features.pixel import cell_average
    from .features.resize import resize_area
    from .fourier import correlate

    t0 = time.perf_counter()
    patch = np.arange(9 * 9 * 3, dtype=np.uint8).reshape(1, 9, 9, 3)
    fhog(patch, 4, arithmetic="release")
    fhog(patch, 4, arithmetic="exact")
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
    _track_a_little()
    return time.perf_counter() - t0


def _track_a_little() -> None:
    """Two frames of every preset on a synthetic scene, colour and grey, with a large target
    (a pyramid-sized window) and a small one.

    Why: Numba compiles (or loads) one specialisation per argument layout, and the trackers
    pass views the calls above do not (a transposed fHOG output, strided windows); loading
    those on the first real frame added ~5 ms to it (measured with ``benchmarks/speed.py``).
    The first tracker of a process also builds FFT plans and feature buffers.
    """
    from .errors import ColorNamesNotFoundError
    from .presets import PRESETS
    from .registry import create_tracker

    yy, xx = np.mgrid[0:480, 0:480]
    frame = np.stack([(xx * 3 + yy) % 256, (yy * 5) % 256, (xx * yy) % 256], -1).astype(np.uint8)
    shifted = np.roll(frame, (3, 2), axis=(0, 1))
    for name in PRESETS:
        for image, later in ((frame, shifted), (frame[..., 0], shifted[..., 0])):
            for box in ((140.0, 140.0, 200.0, 200.0), (200.0, 220.0, 40.0, 30.0)):
                tracker = create_tracker(name)
                try:
                    tracker.init(image, box)
                except ColorNamesNotFoundError:
                    break  # ARCF-HC on colour needs the table; grey frames still warm it up
                tracker.update(later)


def keep_freed_memory() -> bool:
    """Let glibc reuse freed blocks instead of returning them to the system; True if it did.

    Why: a frame allocates and frees dozens of arrays of 0.1-2 MB (FFT outputs, features).
    glibc serves blocks above its mmap threshold with fresh pages and trims the top of its
    heap once 128 kB are free, so each of them page-faults again on every frame. Measured
    (``arcf-hc``, one core): 13.2 -> 12.5 ms per frame on S0310, 15.9 -> 14.9 ms on boat1;
    both parameters are needed, either alone is slower than neither, since setting one turns
    off glibc's adaptive threshold. The cost is that the process keeps up to its peak use
    (plus 128 MB of free heap) instead of shrinking between frames. A no-op elsewhere than
    glibc (musl, macOS).
    """
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        ok = libc.mallopt(_M_MMAP_THRESHOLD, 32 << 20) == 1
        ok = libc.mallopt(_M_TRIM_THRESHOLD, 128 << 20) == 1 and ok
    except (OSError, AttributeError) as exc:
        log.debug("mallopt unavailable: %s", exc)
        return False
    return ok
