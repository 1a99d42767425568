"""A CPU's SSE approximate reciprocal square root and reciprocal, replayed from measured tables.

The authors' release computes fHOG with ``RSQRTPS`` / ``RCPPS`` (Piotr's toolbox ``gradMag``):
~12-bit approximations whose last bits differ between CPU vendors, and which decide orientation
bins near their boundaries and hence, on ARCF-H, whole trajectories (``docs/benchmarks.md``,
"Fidelity").
``fhog(arithmetic="release")`` *models* the instructions of the AMD EPYC that traced the release;
an :class:`SSETables` *replays* the real instructions of whichever CPU ``tools/sse_approx_dump.c``
was run on, bit for bit, on any machine.

Table layout (what the dump tool writes and checks exhaustively on its CPU): the result depends
only on the input's exponent and its top 12 mantissa bits, and scales exactly with the exponent:

* ``rsqrt``: 8,192 results for ``x`` in ``[1, 4)``, key ``(exponent parity) * 4096 + top 12
  mantissa bits``; ``rsqrt(x * 4^k) = rsqrt(x) * 2^-k``;
* ``rcp``: 4,096 results for ``x`` in ``[1, 2)``, key = top 12 mantissa bits;
  ``rcp(x * 2^k) = rcp(x) * 2^-k``.

Zero and denormal inputs give ``inf`` (the instructions treat denormals as zero); fHOG's inputs
are squared gradient magnitudes and capped reciprocals, so nothing else outside the normal range
reaches them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Protocol

import numpy as np

__all__ = ["SHIPPED_TABLES", "SSEInstructions", "SSETables", "load_sse_tables", "sse_table_path"]


class SSEInstructions(Protocol):
    """What the release arithmetic needs of a CPU: its ``RSQRTPS`` and ``RCPPS``, elementwise
    on float32 arrays (``out`` has ``x``'s shape and may be ``x``)."""

    def rsqrt_into(self, x: np.ndarray, out: np.ndarray) -> np.ndarray: ...

    def rcp_into(self, x: np.ndarray, out: np.ndarray) -> np.ndarray: ...

    def __hash__(self) -> int: ...  # fHOG caches its tables of every pixel per instruction set

RSQRT_ENTRIES = 1 << 13
RCP_ENTRIES = 1 << 12
#: Largest relative error a table entry may have against the exact value at its bucket's first
#: input: the instructions promise 1.5 * 2^-12; a larger one means the file is not such a table.
_PLAUSIBLE = 2.0**-10
_EXPONENT = 23
_MANTISSA_TOP = 0xFFF << 11


@dataclass(frozen=True, eq=False)
class SSETables:
    """Measured ``RSQRTPS`` / ``RCPPS`` results per input bucket (float32 bit patterns).

    Attributes:
        rsqrt: uint32 ``(8192,)``, the result for the bucket's inputs in ``[1, 4)``.
        rcp: uint32 ``(4096,)``, the result for the bucket's inputs in ``[1, 2)``.
        cpu: the CPU the tables were measured on (from the dump's header), for reports.
    """

    rsqrt: np.ndarray
    rcp: np.ndarray
    cpu: str = "unknown"

    def __post_init__(self) -> None:
        for name, n, exact in (
            ("rsqrt", RSQRT_ENTRIES, lambda x: 1.0 / np.sqrt(x)),
            ("rcp", RCP_ENTRIES, lambda x: 1.0 / x),
        ):
            table = np.asarray(getattr(self, name))
            if table.shape != (n,):
                raise ValueError(f"SSETables: {name} needs {n} entries, got shape {table.shape}")
            table = table.astype(np.uint32)
            first_inputs = (np.uint32(127 << _EXPONENT) + (np.arange(n, dtype=np.uint32) << 11))
            x = first_inputs.view(np.float32).astype(np.float64)
            got = table.view(np.float32).astype(np.float64)
            with np.errstate(invalid="ignore"):
                error = np.abs(got / exact(x) - 1.0)
            bad = np.flatnonzero(~(error <= _PLAUSIBLE))
            if bad.size:
                k = int(bad[0])
                raise ValueError(
                    f"SSETables: {name} entry {k} = {table[k]:08x} is not an approximation of "
                    f"{name}({x[k]!r}) (relative error {error[k]:.2g}); {bad.size} such entries"
                )
            table.setflags(write=False)
            object.__setattr__(self, name, table)

    @classmethod
    def load(cls, path: str | Path) -> SSETables:
        """Read the output of ``tools/sse_approx_dump.c`` (every entry exactly once)."""
        path = Path(path)
        tables = {"rsqrt": np.zeros(RSQRT_ENTRIES, np.uint32),
                  "rcp": np.zeros(RCP_ENTRIES, np.uint32)}
        seen = {name: np.zeros(len(t), bool) for name, t in tables.items()}
        cpu = "unknown"
        with path.open() as lines:
            for number, line in enumerate(lines, 1):
                if line.startswith("# cpu:"):
                    cpu = line[len("# cpu:"):].strip()
                if line.startswith("#") or not line.strip():
                    continue
                try:
                    name, key, bits = line.split()
                    k, value = int(key), int(bits, 16)
                    if name not in tables or not 0 <= k < len(tables[name]) or seen[name][k]:
                        raise ValueError
                    if not 0 <= value < 1 << 32:
                        raise ValueError
                except ValueError:
                    raise ValueError(
                        f"{path}:{number}: expected 'rsqrt|rcp <key> <hex bits>' with each key "
                        f"once (rsqrt 0..{RSQRT_ENTRIES - 1}, rcp 0..{RCP_ENTRIES - 1}), got "
                        f"{line.strip()[:80]!r}"
                    ) from None
                tables[name][k], seen[name][k] = value, True
        for name, done in seen.items():
            if not done.all():
                raise ValueError(f"{path}: {name} has {int((~done).sum())} missing entries "
                                 f"(first: key {int(np.argmin(done))}); is the dump complete?")
        return cls(tables["rsqrt"], tables["rcp"], cpu)

    def rsqrt_into(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``RSQRTPS`` of float32 ``x >= 0`` into float32 ``out`` (same shape; may be ``x``)."""
        bits = np.ascontiguousarray(x, np.float32).view(np.uint32).astype(np.int64)
        exponent = (bits >> _EXPONENT) - 127
        parity = exponent & 1
        key = (parity << 12) | ((bits & _MANTISSA_TOP) >> 11)
        result = self.rsqrt[key].astype(np.int64) - (((exponent - parity) >> 1) << _EXPONENT)
        zero = bits < (1 << _EXPONENT)  # +0 and denormals
        result[zero] = 0x7F800000  # inf
        out.view(np.uint32)[...] = result.astype(np.uint32).reshape(out.shape)
        return out

    def rcp_into(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``RCPPS`` of float32 ``x >= 0`` into float32 ``out`` (same shape; may be ``x``)."""
        bits = np.ascontiguousarray(x, np.float32).view(np.uint32).astype(np.int64)
        exponent = (bits >> _EXPONENT) - 127
        result = self.rcp[(bits & _MANTISSA_TOP) >> 11].astype(np.int64) - (exponent << _EXPONENT)
        result[bits < (1 << _EXPONENT)] = 0x7F800000  # 1/0 = inf
        result[exponent >= 126] = 0  # 1/x tiny (flushed to zero) or 1/inf
        out.view(np.uint32)[...] = result.astype(np.uint32).reshape(out.shape)
        return out


@lru_cache(maxsize=8)
def _load_cached(path: str) -> SSETables:
    return SSETables.load(path)


#: Tables shipped with the package (``arcf/features/tables``, provenance in its README), by the
#: name a preset may give instead of a path.
SHIPPED_TABLES = {"amd-epyc": "sse_amd_epyc.txt"}


def sse_table_path(name_or_path: str | Path) -> Path:
    """The file of a shipped table's name (``"amd-epyc"``: the CPU that traced the release),
    else the path itself."""
    shipped = SHIPPED_TABLES.get(str(name_or_path))
    if shipped is not None:
        return Path(str(resources.files("arcf.features").joinpath("tables", shipped)))
    return Path(name_or_path)


def load_sse_tables(name_or_path: str | Path) -> SSETables:
    """:meth:`SSETables.load` of a shipped table's name or a file, cached per resolved path
    (trackers of one process share it, and with it fHOG's tables of every uint8 pixel)."""
    return _load_cached(str(sse_table_path(name_or_path).resolve()))
