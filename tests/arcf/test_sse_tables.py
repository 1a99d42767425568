"""A CPU's measured RSQRTPS / RCPPS tables: the dump tool, their replay, and fHOG with them.

The release's fHOG runs on these approximate SSE instructions, whose last bits decide orientation
bins and differ between CPUs; ``tools/sse_approx_dump.c`` measures them and ``SSETables`` replays
them. The strongest check is against the instructions themselves: this machine's tables, dumped
here, must reproduce this machine's ``_mm_rsqrt_ps`` / ``_mm_rcp_ps`` bit for bit on any input,
and fHOG with the tables must equal fHOG computed with the real instructions. Those tests need a
C compiler (``.ci/run`` installs gcc) and an x86 CPU.
"""

from __future__ import annotations

import ctypes
import platform
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import arcf
from arcf.errors import UnknownPresetError
from arcf.features.fhog import fhog
from arcf.features.sse import RCP_ENTRIES, RSQRT_ENTRIES, SSETables, load_sse_tables

TOOL = Path(__file__).resolve().parents[2] / "tools" / "sse_approx_dump.c"

#: Our own helper: the packed instructions over an array, for ctypes.
NATIVE_C = r"""
#include <stddef.h>
#include <xmmintrin.h>
void rsqrt_ps(const float *x, float *y, size_t n) {
    for (size_t i = 0; i + 4 <= n; i += 4) _mm_storeu_ps(y + i, _mm_rsqrt_ps(_mm_loadu_ps(x + i)));
}
void rcp_ps(const float *x, float *y, size_t n) {
    for (size_t i = 0; i + 4 <= n; i += 4) _mm_storeu_ps(y + i, _mm_rcp_ps(_mm_loadu_ps(x + i)));
}
"""


def _compiler() -> str:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None or platform.machine().lower() not in ("x86_64", "amd64", "i686", "x86"):
        pytest.skip("needs a C compiler on an x86 CPU (.ci/run installs gcc)")
    return cc


@pytest.fixture(scope="module")
def dumped(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """This machine's tables, measured by the tool (which must find them complete: exit 0)."""
    cc = _compiler()
    d = tmp_path_factory.mktemp("sse")
    exe = d / "sse_approx_dump"
    subprocess.run([cc, "-O2", "-msse2", "-o", str(exe), str(TOOL), "-lm"], check=True)
    out = d / "sse.txt"
    with out.open("w") as f:
        done = subprocess.run([str(exe)], stdout=f, stderr=subprocess.PIPE, text=True,
                              timeout=120)
    assert done.returncode == 0, done.stderr
    assert "0 not constant, 0 not scaling" in done.stderr
    return out


@pytest.fixture(scope="module")
def native(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """``(rsqrt, rcp)``: the CPU's own instructions on float32 arrays."""
    cc = _compiler()
    d = tmp_path_factory.mktemp("native")
    (d / "native.c").write_text(NATIVE_C)
    lib_path = d / "libnative.so"
    subprocess.run([cc, "-O2", "-msse2", "-shared", "-fPIC", "-o", str(lib_path),
                    str(d / "native.c")], check=True)
    lib = ctypes.CDLL(str(lib_path))

    def wrap(fn):  # type: ignore[no-untyped-def]
        def call(x: np.ndarray, out: np.ndarray) -> np.ndarray:
            flat = np.ascontiguousarray(x, np.float32).reshape(-1)
            n = flat.size
            padded = np.ones((n + 3) // 4 * 4, np.float32)
            padded[:n] = flat
            res = np.empty_like(padded)
            fn(padded.ctypes.data_as(ctypes.c_void_p), res.ctypes.data_as(ctypes.c_void_p),
               ctypes.c_size_t(padded.size))
            out.reshape(-1)[...] = res[:n]
            return out
        return call

    return wrap(lib.rsqrt_ps), wrap(lib.rcp_ps)


def _positive_floats(n: int, lo_exp: int, hi_exp: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    exponent = rng.integers(127 + lo_exp, 127 + hi_exp, n, dtype=np.uint32)
    mantissa = rng.integers(0, 1 << 23, n, dtype=np.uint32)
    return ((exponent << 23) | mantissa).view(np.float32)


def test_replay_equals_the_instructions_bit_for_bit(dumped: Path, native) -> None:
    """Any exponent fHOG can meet, every mantissa pattern: the table is the instruction."""
    rsqrt, rcp = native
    tables = load_sse_tables(dumped)
    x = _positive_floats(1 << 20, -60, 61)
    x[:5] = [0.0, 1.0, 256.0, 2.0, np.nextafter(np.float32(4), np.float32(0))]
    for replay, real in ((tables.rsqrt_into, rsqrt), (tables.rcp_into, rcp)):
        got = replay(x, np.empty_like(x))
        want = real(x, np.empty_like(x))
        np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))
    assert tables.cpu != "unknown"


@dataclass(frozen=True)
class Native:
    """This CPU's own instructions, called through ctypes, as fHOG's SSE instructions."""

    rsqrt_into: Callable[[np.ndarray, np.ndarray], np.ndarray]
    rcp_into: Callable[[np.ndarray, np.ndarray], np.ndarray]


def test_fhog_with_tables_equals_fhog_on_the_instructions(dumped: Path, native) -> None:
    """The release arithmetic with the replayed tables is exactly the release arithmetic run on
    this CPU's instructions (including the doubled gradient and the capped reciprocal), and it
    differs from the model of the AMD EPYC: the tables matter."""
    rng = np.random.default_rng(3)
    smooth = np.cumsum(np.cumsum(rng.normal(0, 3, (2, 96, 120, 3)), axis=1), axis=2)
    patches = np.clip(smooth - smooth.min() + rng.normal(0, 4, smooth.shape), 0, 255)
    patches = patches.astype(np.uint8)
    tables = load_sse_tables(dumped)
    replayed = fhog(patches, 4, arithmetic=tables)  # uint8: tables of every pixel, fused
    model = fhog(patches, 4, arithmetic="release")
    # float32 pixels take the separate steps, which call the instructions themselves
    on_the_cpu = fhog(patches.astype(np.float32), 4, arithmetic=Native(*native))
    np.testing.assert_array_equal(replayed, on_the_cpu)
    np.testing.assert_array_equal(fhog(patches.astype(np.float32), 4, arithmetic=tables),
                                  replayed)
    assert np.abs(replayed - model).max() > 1e-6


def test_tracker_replays_the_tables(dumped: Path) -> None:
    """The preset option reaches every fHOG the tracker computes (features and scale filter)."""
    tracker = arcf.create_tracker("arcf-hc", fhog_sse_table=str(dumped))
    frame = np.random.default_rng(1).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    tracker.init(frame, (50, 40, 30, 24))
    assert tracker.layout.extractor.fhog_arithmetic is load_sse_tables(dumped)
    assert tracker.state.scale_filter.fhog_arithmetic is load_sse_tables(dumped)
    tracker.update(frame)


def _valid_lines() -> list[str]:
    """A synthetic complete table: the exact values at each bucket's first input."""
    first = (np.uint32(127 << 23) + (np.arange(RSQRT_ENTRIES, dtype=np.uint32) << 11))
    rs = (1 / np.sqrt(first.view(np.float32).astype(np.float64))).astype(np.float32)
    rc = (1 / first[:RCP_ENTRIES].view(np.float32).astype(np.float64)).astype(np.float32)
    return (["# cpu: synthetic"]
            + [f"rsqrt {k} {b:08x}" for k, b in enumerate(rs.view(np.uint32))]
            + [f"rcp {k} {b:08x}" for k, b in enumerate(rc.view(np.uint32))])


def test_load_reads_a_complete_table(tmp_path: Path) -> None:
    path = tmp_path / "t.txt"
    path.write_text("\n".join(_valid_lines()) + "\n")
    tables = SSETables.load(path)
    assert tables.cpu == "synthetic"
    x = np.array([1.0, 4.0, 16.0, 0.25], np.float32)
    np.testing.assert_array_equal(tables.rsqrt_into(x, np.empty_like(x)), [1, 0.5, 0.25, 2])
    np.testing.assert_array_equal(tables.rcp_into(x, np.empty_like(x)), [1, 0.25, 0.0625, 4])


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda lines: lines[:-1], "missing entries"),
        (lambda lines: [*lines, lines[5]], "each key once"),
        (lambda lines: [*lines[:3], "rsqrt 2 zz", *lines[4:]], "each key once"),
        (lambda lines: [*lines[:3], "rsqrt 99999 3f800000", *lines[4:]], "each key once"),
        (lambda lines: [*lines[:3], "rsqrt 2 3f800000 9", *lines[4:]], "each key once"),
        (lambda lines: [*lines[:3], "rsqrt 2 40000000", *lines[4:]], "not an approximation"),
    ],
    ids=["truncated", "duplicate", "bad-hex", "bad-key", "extra-field", "wrong-value"],
)
def test_load_refuses_a_broken_table(tmp_path: Path, edit, words: str) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "t.txt"
    path.write_text("\n".join(edit(_valid_lines())) + "\n")
    with pytest.raises(ValueError, match=words):
        SSETables.load(path)


def test_tracker_reports_an_unreadable_table(tmp_path: Path) -> None:
    with pytest.raises(UnknownPresetError, match="fhog_sse_table"):
        arcf.create_tracker("arcf-h", fhog_sse_table=str(tmp_path / "absent.txt"))
    (tmp_path / "junk.txt").write_text("hello\n")
    with pytest.raises(UnknownPresetError, match="fhog_sse_table"):
        arcf.create_tracker("arcf-h", fhog_sse_table=str(tmp_path / "junk.txt"))


def test_the_tracing_cpus_table_ships_with_the_package() -> None:
    """RELEASE_COMPATIBLE replays the AMD EPYC's instructions on any CPU: the table is package
    data, loaded by name, and (where the shared data is present) the very file measured there."""
    from importlib import resources

    import arcf
    from arcf.data import data_root
    from arcf.features.sse import SHIPPED_TABLES, sse_table_path

    path = sse_table_path("amd-epyc")
    assert path.is_file() and path.name == SHIPPED_TABLES["amd-epyc"]
    assert path.parent.name == "tables" and (path.parent / "README.md").is_file()
    assert resources.files("arcf.features").joinpath("tables", path.name).is_file()
    tables = load_sse_tables("amd-epyc")
    assert tables is load_sse_tables(path) and tables.cpu == "AMD EPYC"
    shared = data_root() / "reference_release" / "sse_amd_epyc.txt"
    if shared.is_file():
        assert shared.read_bytes() == path.read_bytes()
    assert arcf.RELEASE_COMPATIBLE["fhog_sse_table"] == "amd-epyc"
    tracker = arcf.create_tracker("arcf-h", **arcf.RELEASE_COMPATIBLE)
    assert tracker._fhog_arithmetic is tables
    with pytest.raises(UnknownPresetError):
        arcf.create_tracker("arcf-h", fhog_sse_table="no-such-table")
