"""Per-thread scratch buffers and the batch's chunk size: fHOG's memory, kept warm."""

from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np

#: Working-set budget per chunk of a batch (bytes), sized for a 2-4 MB L2 cache; see
#: ``chunk_size``.
_CHUNK_BYTES = 3 << 20

def chunk_size(height: int, width: int, hb: int, wb: int, n_orients: int) -> int:
    """Images per chunk: the batch is vectorised, but in chunks whose intermediates fit in L2.

    Why: a batch of five 200x200 patches in one go was ~1.5x slower per patch than one at a
    time, and 33 tiny patches at cell size 1 ~2x slower, because the intermediates (~64 B per
    pixel, ~(16 (3n + 4) + 16 n) B per cell) then spill to L3 / RAM.
    """
    per_image = 64 * height * width + (16 * (3 * n_orients + 4) + 16 * n_orients) * hb * wb
    return max(1, _CHUNK_BYTES // per_image)


_SCRATCH = threading.local()
_SCRATCH_MAX_BYTES = 64 << 20  # larger requests (huge images) are plain allocations


def scratch(name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """Uninitialised work array, reused across calls (per thread, one buffer per ``name``).

    Why: on the tracker's patch sizes every intermediate is 100 kB - 2 MB, above glibc's mmap
    threshold, and a fresh one page-faults on first touch on every call; measured, that cost
    more than the arithmetic (e.g. ``cv2.split`` of 5 patches: 0.75 ms into fresh arrays vs
    0.04 ms into reused ones).  Buffers only grow, so memory is bounded by the largest batch
    seen.  Callers must not let two live arrays share a name, nor return a scratch array.
    """
    pool: dict[Any, np.ndarray] = _SCRATCH.__dict__  # this thread's dict
    key = (name, shape, dtype)
    arr = pool.get(key)
    if arr is not None:
        return arr
    dt = np.dtype(dtype)
    nbytes = math.prod(shape) * dt.itemsize
    if nbytes > _SCRATCH_MAX_BYTES:
        return np.empty(shape, dt)
    base = pool.get(name)
    if base is None or base.nbytes < nbytes:
        # Grow; forget the views of the old buffer so that it can be freed.
        for k in [k for k in pool if isinstance(k, tuple) and k[0] == name]:
            del pool[k]
        base = pool[name] = np.empty(max(nbytes, 64), np.uint8)
    if len(pool) > 512:  # many different shapes: start over rather than grow without bound
        pool.clear()
        pool[name] = base
    arr = pool[key] = base[:nbytes].view(dt).reshape(shape)
    return arr
