"""The features' compiled kernels: Numba's ``njit``, cached on disk where that is possible."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numba

log = logging.getLogger("arcf.features")

_OPTIONS: dict[str, Any] = {"nogil": True, "boundscheck": False}


def kernel(fn: Callable[..., Any]) -> Any:
    """``numba.njit(cache=True, nogil=True, boundscheck=False)``, or without ``cache`` if need be.

    Why: Numba refuses to define a cached function at all (it raises at import) when none of
    its cache locations is writable: the package's ``__pycache__``, ``$NUMBA_CACHE_DIR``, the
    user's cache directory. That is the normal state of a hardened read-only container. The
    kernel is then compiled in memory by each process that uses it (a few seconds, once),
    instead of the library failing to import.
    """
    try:
        return numba.njit(cache=True, **_OPTIONS)(fn)
    except RuntimeError as exc:  # "cannot cache function ...: no locator available"
        log.info("Numba cache unavailable (%s); %s compiles in memory", exc, fn.__qualname__)
        return numba.njit(cache=False, **_OPTIONS)(fn)
