"""The library's compiled kernels: Numba's ``njit``, cached on disk where that is possible."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numba
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

log = logging.getLogger(__name__)

_OPTIONS: dict[str, Any] = {"nogil": True, "boundscheck": False, "error_model": "numpy"}


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


@intrinsic
def _fma32(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    """``a * b + c`` in float32 with a single rounding (LLVM's ``fma``), inside kernels.

    Why: NumPy multiplies complex64 arrays as ``re = fma(ar, br, -(ai bi))``, ``im = fma(ar,
    bi, ai br)`` on CPUs with FMA (measured: equal on 10^6 random products, while the plain
    formula differs on 44 %). Kernels that replace NumPy's complex products use this to give
    the same bits, so the trackers' boxes do not change with the implementation.
    """
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        f32 = ir.FloatType()
        fn = builder.module.declare_intrinsic("llvm.fma", [f32], ir.FunctionType(f32, [f32] * 3))
        return builder.call(fn, args)

    return sig, codegen


if TYPE_CHECKING:
    def fma32(a: float, b: float, c: float) -> float:
        """What kernels call: Numba supplies the typing context of the intrinsic."""
        ...
else:
    fma32 = _fma32
