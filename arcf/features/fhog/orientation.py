"""Step 2, exact arithmetic: each pixel's contrast-sensitive orientation bin, from sign tests
and ratio thresholds (no ``atan2``)."""

from __future__ import annotations

from fractions import Fraction
from functools import lru_cache

import numpy as np

from .scratch import scratch


@lru_cache(maxsize=16)
def orientation_tables(n_orients: int) -> tuple[tuple[float, ...], np.ndarray]:
    """Thresholds on ``|gy| / |gx|`` and the code -> contrast-sensitive-bin table.

    The toolbox bin is ``o = floor(theta * 2n / 2pi + 1/2) mod 2n`` with ``theta`` in
    ``[0, 2pi)``, i.e. the number of bin boundaries ``(k + 1/2) * 180 / n`` degrees that do not
    exceed theta.  Folding theta by the signs of gx and gy into ``theta'`` in ``[0, 90]``
    reduces this to ``q``, the number of thresholds below ``|gy| / |gx|``: one per boundary
    ``b`` in (0, 90) at ``tan(b)``.  A boundary whose tangent is rational can be hit exactly,
    and there the rounding direction depends on the quadrant, so it gets a state of its own
    (two thresholds): 45 degrees (``|gx| == |gy|``, when n = 2, 6, 10, ...) and 90 degrees
    (``gx == 0``, when n is odd; e.g. a vertical gradient goes to bin 5 = int(4.5 + 0.5) for
    n = 9, as in exact arithmetic and in the toolbox).  By Niven's theorem these are the only
    rational tangents.  The pair (quadrant, q) then determines the bin; the table is filled by
    evaluating the exact formula, in rational arithmetic, at a representative angle of every
    state, so it is correct by construction for any n.

    Returns the increasing float32 thresholds (tested with ``>``) and a 256-entry uint8 table
    indexed by ``code = q + n_q * (2 * [gy < 0] + [gx < 0])``, ``n_q = len(thresholds) + 1``.
    """
    step = Fraction(180, n_orients)  # bin width in degrees (20 for n = 9)
    f32 = np.float32
    thresholds: list[float] = []
    states: list[Fraction] = []  # representative folded angle of each q value
    lo = Fraction(0)
    k = 0
    while (b := (k + Fraction(1, 2)) * step) <= 90:
        states.append((lo + b) / 2)  # strictly between the previous boundary and b
        if b == 45:  # tan = 1: separate states for ratio < 1, == 1, > 1
            thresholds += [float(np.nextafter(f32(1), f32(0))), 1.0]
            states.append(b)
        elif b == 90:  # ratio == inf (gx == 0): "> float32 max"
            thresholds.append(float(np.finfo(f32).max))
            states.append(b)
        else:
            thresholds.append(float(f32(np.tan(np.deg2rad(float(b))))))
        lo = b
        k += 1
    if lo < 90:
        states.append((lo + 90) / 2)  # last interval, up to and including 90 degrees
    n_q = len(states)
    assert n_q == len(thresholds) + 1 and 4 * n_q <= 256

    def exact_bin(theta: Fraction) -> int:
        return int((theta / step + Fraction(1, 2)) // 1) % (2 * n_orients)

    table = np.zeros(256, np.uint8)
    for q, tp in enumerate(states):
        # Quadrant (2 * [gy < 0] + [gx < 0]) -> theta.  Zero components compare as
        # non-negative; the resulting angles 0 / 90 / 180 / 270 are all mapped correctly.
        for quad, theta in ((0, tp), (1, 180 - tp), (2, (360 - tp) % 360), (3, 180 + tp)):
            table[q + n_q * quad] = exact_bin(theta)
    table.setflags(write=False)
    return tuple(thresholds), table


def orientation_code(
    gx: np.ndarray, gy: np.ndarray, n_orients: int, out: np.ndarray | None = None
) -> np.ndarray:
    """uint8 code of each gradient direction; ``orientation_tables`` maps it to the bin.

    Exact (no ``atan2``): besides sign tests, only ``|gy| / |gx| > threshold`` is evaluated, in
    float32.  For every gradient an 8-bit image can produce this was checked exhaustively to
    agree with exact arithmetic (the closest such direction is ~5e-7, relative, away from an
    irrational boundary: 8x the float32 rounding), and likewise for images with values k/4;
    rational boundaries (45 / 90 degrees) are compared exactly.  For arbitrary float input the
    result is exact up to float32 rounding of the ratio (atan2 in float32 would be no better).
    """
    thresholds, _ = orientation_tables(n_orients)
    n_q = len(thresholds) + 1
    code = np.empty(gx.shape, np.uint8) if out is None else out
    flag = scratch("flag", gx.shape, np.bool_)
    ratio = scratch("ratio", gx.shape, np.float32)
    np.less(gy, 0, out=code.view(np.bool_))
    code += code
    code += np.less(gx, 0, out=flag)
    code *= np.uint8(n_q)  # quadrant * n_q
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(gy, gx, out=ratio)  # +-inf for vertical gradients, nan for zero gradients
    np.abs(ratio, out=ratio)
    for t in thresholds:
        code += np.greater(ratio, np.float32(t), out=flag)
    return code


def orientation_bins(gx: np.ndarray, gy: np.ndarray, n_orients: int = 9) -> np.ndarray:
    """Contrast-sensitive bin (uint8, ``0 .. 2n-1``) of every gradient direction (gx, gy).

    Equals ``int(theta * 2n / 2pi + 0.5) mod 2n`` with ``theta = atan2(gy, gx)`` in
    ``[0, 2pi)``, evaluated exactly (the histogram uses the code directly; handy for tests).
    """
    _, table = orientation_tables(n_orients)
    gx = np.asarray(gx, np.float32)
    gy = np.asarray(gy, np.float32)
    return table[orientation_code(gx, gy, n_orients)]
