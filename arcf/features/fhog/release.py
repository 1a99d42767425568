"""The release's approximate arithmetic (``arithmetic="release"``) and its tables.

The toolbox's SSE ``gradMag`` as the authors' release ran it: magnitude and orientation from
an approximate reciprocal square root (``RSQRTPS``) and reciprocal (``RCPPS``) and an acos
lookup table. The instructions are either modelled (:data:`SSE_MODEL`, the AMD EPYC that
traced the release, what ``"release"`` computes) or replayed from a CPU's measured tables
(:class:`~arcf.features.sse.SSETables`); both are :class:`~arcf.features.sse.SSEInstructions`.
On uint8 images every possible pixel is tabulated once per instruction set
(:func:`release_pixel_tables`).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from ..._jit import kernel
from ..sse import SSEInstructions
from .gradient import GRADIENT_SPAN, MAX_GRADIENT
from .scratch import scratch

#: The toolbox's ``PI`` (``3.14159265f``) and its acos table: ``a[i] ~ acos(i / 10000)`` for
#: ``i = -10000 .. 9999`` plus 10 entries of padding on either side.
_PI_F32 = np.float32(3.14159265)
_ACOS_N = 10000
_ACOS_PAD = 10
ACOS_OFFSET = _ACOS_N + _ACOS_PAD  # array index of i = 0
ACOS_LEN = 2 * ACOS_OFFSET

#: ``min(rsqrt(m2), 1e10f)`` on the doubled gradient's ``4 m2``: the cap halves too.
HALF_RSQRT_CAP = np.float32(5e9)
_SIGN_BIT = np.uint32(0x80000000)
#: The modelled rsqrt keeps 13 significant bits (12 of float64's 52 fraction bits): add half a
#: unit of the last kept bit, then clear the 40 dropped bits.
_RSQRT_DROPPED_BITS = 52 - 12
RSQRT_HALF_UNIT = np.int64(1 << (_RSQRT_DROPPED_BITS - 1))
RSQRT_MASK = np.int64(~((1 << _RSQRT_DROPPED_BITS) - 1))
#: ``Gx * _m * 10000`` on the doubled gradient and the halved ``_m``: same real product.
ACOS_MULT = np.float32(_ACOS_N)


@lru_cache(maxsize=1)
def release_acos_table() -> np.ndarray:
    """The toolbox's ``acosTable()``: float32 ``a[i + 10010]`` for ``i = -10010 .. 10009``.

    ``a[i] = float(acos(i / 10000.f))`` for ``-10000 <= i < 10000``, ``PI`` below, ``0`` above,
    then every entry with ``i < 1000`` larger than ``PI - 1e-6f`` is clamped to ``PI - 1e-6f``
    (float32 arithmetic throughout; in effect ``i = -10010 .. -10000``).
    """
    i = np.arange(-ACOS_OFFSET, ACOS_OFFSET)
    inside = (i >= -_ACOS_N) & (i < _ACOS_N)
    x = i[inside].astype(np.float32) / np.float32(_ACOS_N)  # float32 division, as in C
    table = np.zeros(ACOS_LEN, np.float32)
    table[i < -_ACOS_N] = _PI_F32
    table[inside] = np.arccos(x.astype(np.float64)).astype(np.float32)
    limit = _PI_F32 - np.float32(1e-6)
    table[(i < _ACOS_N // 10) & (table > limit)] = limit
    table.setflags(write=False)
    return table


@lru_cache(maxsize=16)
def release_bin_table(n_orients: int) -> np.ndarray:
    """Contrast-sensitive bin (uint8) of every acos-table key, ``(2, 20020)`` flattened.

    Key ``k = i + 10010 + 20020 * [gy < 0]`` with ``i`` the truncated table index: the
    toolbox's orientation is ``O = a[i] (+ PI if gy < 0)`` and its bin (``gradQuantize``,
    non-interpolating) ``o0 = (int)(O * oMult + 0.5f)`` with ``oMult = (float)2n / (2 * PI)``,
    ``o0 = 0`` if ``o0 >= 2n``, all in float32.  Tabulating the bin per key replaces four
    float passes per pixel by one lookup.
    """
    table = release_acos_table()
    n_bins = 2 * n_orients
    o_mult = np.float32(n_bins) / (np.float32(2) * _PI_F32)
    theta = np.concatenate([table, table + _PI_F32])  # float32 sums
    bins = (theta * o_mult + np.float32(0.5)).astype(np.int64)  # >= 0: truncation
    bins[bins >= n_bins] = 0
    out = bins.astype(np.uint8)
    out.setflags(write=False)
    return out


def release_orientation(
    gx: np.ndarray,
    gy: np.ndarray,
    mag2: np.ndarray,
    n_orients: int,
    plane: int,
    instructions: SSEInstructions,
) -> np.ndarray:
    """Flat orientation-plane offset (int32, ``N * h0 * w0``) of every pixel, release arithmetic.

    On entry ``gx``, ``gy``, ``mag2`` are the *doubled* gradient and ``4 m2``; on exit
    ``mag2`` holds the capped approximate ``rsqrt(4 m2) = _m / 2`` (``release_magnitude``
    turns it into ``2 M``).  Toolbox ``gradMag``: ``_m = min(rsqrt(m2), 1e10f)``,
    ``Gx = gx * _m * 10000`` (float32, in that order), Gx's sign flipped where gy's *sign bit*
    is set (so ``gy = -0.0`` flips too), ``i = (int) Gx`` (truncation), ``O = a[i]``, plus
    ``PI`` where ``gy < 0`` (false for -0.0).  Since ``(2 gx) * (_m / 2) == gx * _m`` exactly,
    every rounding is the toolbox's.  ``rsqrt`` is the instructions' (a measured table is exact
    for ``4 m2`` too: it scales with the exponent).
    """
    half_m = instructions.rsqrt_into(mag2, out=mag2)
    start = scratch("start", (gx.size,), np.int32)
    release_keys(gx.reshape(-1), gy.reshape(-1), half_m.reshape(-1),
                  release_plane_offsets(n_orients, plane), start)
    return start


@kernel
def release_keys(gx, gy, half_m, offsets, start):  # pragma: no cover - compiled
    """``release_orientation``'s per-pixel steps after ``rsqrt``, in one pass.

    ``half_m = min(half_m, cap)`` (in place, as the magnitude needs it), ``t = (gx half_m)
    10000`` in float32, negated where gy's sign bit is set (negation flips exactly that bit),
    clipped to the table, truncated toward zero, offset into the ``gy < 0`` half of the table
    where ``gy < 0``, and looked up in ``offsets``. A NaN (impossible for finite pixels) reads
    the table's centre.
    """
    cap = np.float32(HALF_RSQRT_CAP)
    mult = np.float32(ACOS_MULT)
    lo, hi = np.float32(-ACOS_OFFSET), np.float32(ACOS_OFFSET - 1)
    # Written without branches (the sign flip is a product with +-1, exact): with real
    # gradients their outcomes are random, and mispredictions doubled the fused kernel's time.
    for p in range(gx.size):
        hm = min(half_m[p], cap)
        half_m[p] = hm
        t = (gx[p] * hm) * mult
        t = t * np.float32(math.copysign(1.0, gy[p]))
        t = max(min(t, hi), lo)
        key = (int(t) if t == t else 0) + ACOS_OFFSET
        key += ACOS_LEN if gy[p] < 0 else 0
        start[p] = offsets[key]


@lru_cache(maxsize=16)
def release_plane_offsets(n_orients: int, plane: int) -> np.ndarray:
    """``release_bin_table`` times the accumulator's plane size (int32, cached per layout)."""
    offsets = release_bin_table(n_orients).astype(np.int32) * np.int32(plane)
    offsets.setflags(write=False)
    return offsets


def release_magnitude(half_m: np.ndarray, instructions: SSEInstructions) -> np.ndarray:
    """``2 M = 2 rcp(_m) = rcp(_m / 2)``, in place (input: ``release_orientation``'s output)."""
    return instructions.rcp_into(half_m, out=half_m)


def release_rsqrt(x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Model of SSE ``_mm_rsqrt_ps``: ``1 / sqrt(x)`` rounded to 13 significant bits.

    Evaluated in float64 (error < 2^-52, far from any rounding boundary: ``1 / sqrt(x)`` of a
    float32 ``x`` is never a 13-bit midpoint), then rounded to nearest by adding half a unit of
    the 13th bit to the bit pattern and clearing the 40 bits below; exact in float32.  ``x = 0``
    gives ``inf`` (as the instruction does).  See ``fhog`` for why this model.
    """
    v = scratch("rel_f64", x.shape, np.float64)
    np.copyto(v, x)
    np.sqrt(v, out=v)
    with np.errstate(divide="ignore"):
        np.divide(1.0, v, out=v)
    bits = v.view(np.int64)
    bits += RSQRT_HALF_UNIT
    bits &= RSQRT_MASK  # inf stays inf: its low bits are zero and the carry stops there
    np.copyto(out, v, casting="same_kind")
    return out


def release_rcp(x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Model of SSE ``_mm_rcp_ps``: correctly rounded float32 ``1 / x`` (see ``fhog``)."""
    with np.errstate(divide="ignore"):
        return np.divide(np.float32(1), x, out=out)


class SSEModel:
    """The modelled instructions of the AMD EPYC that traced the release: ``rsqrt`` rounded to
    13 significant bits, ``rcp`` correctly rounded (see :func:`~arcf.features.fhog.fhog`).
    ``fhog(arithmetic="release")`` computes exactly this; passing :data:`SSE_MODEL` gives the
    same bits through the general path (tables of every pixel built from this object for uint8
    images, the separate steps for other pixels)."""

    cpu = "model of the AMD EPYC that traced the release"

    def rsqrt_into(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        return release_rsqrt(x, out)

    def rcp_into(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        return release_rcp(x, out)


SSE_MODEL = SSEModel()




@lru_cache(maxsize=8)
def release_pixel_tables(n_orients: int, instructions: SSEInstructions = SSE_MODEL
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Every possible pixel of a uint8 image, through the release arithmetic with
    ``instructions`` (cached per instruction set: a table file is loaded once per process).

    Returns ``bins`` (uint8) and ``mags`` (float32, ``2 M``), both indexed by
    ``(gy + 510) * 1021 + (gx + 510)`` for the doubled gradient ``gx``, ``gy``.

    Why: on uint8 pixels the doubled gradient components are integers in [-510, 510] (never
    ``-0.0``: ``x - x = +0``), and a pixel's orientation bin and magnitude depend on nothing
    else. Tabulating them with the very functions the per-pixel path calls makes the kernel's
    work per pixel two lookups instead of a float64 ``1 / sqrt``, two roundings and the key
    arithmetic: the same bits (by construction, and pinned by the golden hashes), at 0.6x the
    kernel's time. Natural images' gradients are small, so the lookups stay in a few
    kilobytes around the tables' centre. Built once per process in ~20 ms; 5 MB.
    """
    g = np.arange(-MAX_GRADIENT, MAX_GRADIENT + 1, dtype=np.float32)
    bins = np.empty((GRADIENT_SPAN, GRADIENT_SPAN), np.uint8)
    mags = np.empty((GRADIENT_SPAN, GRADIENT_SPAN), np.float32)
    offsets = release_plane_offsets(n_orients, 1)
    rows = 64  # a few rows of the table at a time: the model's scratch stays small
    for top in range(0, GRADIENT_SPAN, rows):
        gy = np.repeat(g[top : top + rows], GRADIENT_SPAN)
        gx = np.tile(g, len(gy) // GRADIENT_SPAN)
        m2 = gy * gy + gx * gx  # exact: integers below 2^24, as the kernel's fma gives them
        half_m = instructions.rsqrt_into(m2, out=m2)
        start = np.empty(gx.size, np.int32)
        release_keys(gx, gy, half_m, offsets, start)
        bins[top : top + rows] = start.reshape(-1, GRADIENT_SPAN)
        mags[top : top + rows] = instructions.rcp_into(half_m, out=half_m).reshape(
            -1, GRADIENT_SPAN)
    flat_bins, flat_mags = bins.reshape(-1), mags.reshape(-1)
    for arr in (flat_bins, flat_mags):
        arr.setflags(write=False)
    return flat_bins, flat_mags
