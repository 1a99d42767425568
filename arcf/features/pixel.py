"""Pixel-level features averaged over cells: grayscale and Color Names (ARCF-HC).

Both follow ECO's ``average_feature_region``: the mean over each cell x cell block, blocks aligned
to the top-left corner, giving a floor(H/cell) x floor(W/cell) grid like fHOG's.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from .._jit import kernel
from ..data import COLORNAMES_ENV, default_colornames_path
from ..errors import ColorNamesNotFoundError

CN_SHA256 = "e056387d4bc872167cfb2519693d7dce9a25d07dc3a867c5b22e86d2caf5689c"


def cell_average(maps: np.ndarray, cell: int) -> np.ndarray:
    """Mean over cell x cell blocks of (N, H, W, C) maps -> (N, H//cell, W//cell, C) float32.

    Computed as the release does (ECO's ``average_feature_region``): a float32 integral image
    (``cumsum`` down the rows, then along the columns), four corner reads per cell, divided by
    the cell area. The rounding of that running sum differs from a block mean by up to 3e-5 on a
    200x200 patch; matching it makes the grey and Color Names blocks equal to the release's bit
    for bit. The integral image is never stored: one running row of column sums is enough,
    summed along the row once per cell row (``_cell_sums``).
    """
    n, h, w, c = maps.shape
    out = np.empty((n, h // cell, w // cell, c), np.float32)
    if out.size:
        _cell_sums(np.ascontiguousarray(maps, np.float32), _NO_INDEX, _NO_TABLE, cell, out)
    return out


#: Placeholders for the unused inputs of ``_cell_sums``.
_NO_MAPS = np.zeros((0, 0, 0, 0), np.float32)
_NO_INDEX = np.zeros((0, 0, 0), np.int32)
_NO_TABLE = np.zeros((0, 0), np.float32)


@kernel
def _cell_sums(maps, index, table, cell, out):  # pragma: no cover - compiled
    """``cell_average``'s kernel; the same float32 additions in the same order as the release.

    The maps are ``maps`` (N, H, W, C), or, when ``table`` (K, C) is not empty, the rows of
    ``table`` that ``index`` (N, H, W) selects (Color Names, without materialising the
    looked-up maps).

    ``col[x]`` is the integral image's column sum down to the current row (``cumsum`` along
    the rows); at the bottom row of each cell row, its running sum along the row gives the
    integral image at the cell corners (``cur``), and each cell is ``((I11 - I10) - I01) + I00``
    over the cell area, as MATLAB evaluates the release's expression.
    """
    n, c = out.shape[0], out.shape[3]
    hb, wb = out.shape[1], out.shape[2]
    width = wb * cell
    area = np.float32(cell * cell)
    col = np.empty((width, c), np.float32)
    prev = np.empty((wb + 1, c), np.float32)
    cur = np.empty((wb + 1, c), np.float32)
    run = np.empty(c, np.float32)
    for i in range(n):
        col[:] = 0.0
        prev[:] = 0.0
        for r in range(hb * cell):
            if table.shape[0] == 0:
                for x in range(width):
                    for k in range(c):
                        col[x, k] += maps[i, r, x, k]
            else:
                for x in range(width):
                    values = table[index[i, r, x]]
                    for k in range(c):
                        col[x, k] += values[k]
            if (r + 1) % cell:
                continue
            run[:] = 0.0
            cur[0, :] = 0.0
            for x in range(width):
                for k in range(c):
                    run[k] += col[x, k]
                if (x + 1) % cell == 0:
                    cur[(x + 1) // cell, :] = run
            rb = r // cell
            for j in range(wb):
                for k in range(c):
                    s = ((cur[j + 1, k] - cur[j, k]) - prev[j + 1, k]) + prev[j, k]
                    out[i, rb, j, k] = s / area
            prev[:] = cur


#: MATLAB's ``rgb2gray`` weights: the first row of the inverse of the NTSC (YIQ) matrix.
RGB2GRAY = np.array([0.298936021293775, 0.587043074451121, 0.114020904255103])


def gray_features(patches: np.ndarray, cell: int) -> np.ndarray:
    """Grayscale channel: gray - 0.5 with gray in [0, 1], averaged per cell.

    (N, H, W, 1|3) uint8 **RGB** -> (N, h, w, 1). As the release (ECO's ``get_colorspace``), a
    colour patch goes through ``rgb2gray(single(im) / 255)``: the weighted sum of the float
    image, not of 8-bit values rounded to an 8-bit grey (that rounding moves a cell by up to
    1.7e-3).
    """
    scaled = patches.astype(np.float32) / np.float32(255.0)  # single(im) / 255, as rounded
    if patches.shape[-1] == 3:
        gray = (scaled.astype(np.float64) @ RGB2GRAY).astype(np.float32)[..., None]
    else:
        gray = scaled
    gray -= np.float32(0.5)
    return cell_average(gray, cell)


class ColorNames:
    """The 32768 x 10 Color Names lookup (van de Weijer et al. 2009), normalised (``CNnorm``).

    The table is data we may not redistribute, so it is loaded from a path: the argument, else
    ``$ARCF_COLORNAMES``, else ``<data root>/colornames/cn_norm_32768x10.npy``.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else default_colornames_path()
        self.table = _load_table(str(self.path.resolve()) if self.path.exists() else str(self.path))

    def __call__(self, patches: np.ndarray, cell: int) -> np.ndarray:
        """(N, H, W, 3) RGB uint8 -> (N, H//cell, W//cell, 10) float32."""
        p = patches.astype(np.int32) >> 3
        index = p[..., 0] + 32 * p[..., 1] + 1024 * p[..., 2]  # R//8 + 32 G//8 + 1024 B//8
        n, h, w, _ = patches.shape
        out = np.empty((n, h // cell, w // cell, self.table.shape[1]), np.float32)
        if out.size:  # = cell_average(self.table[index], cell), without the looked-up maps
            _cell_sums(_NO_MAPS, index, self.table, cell, out)
        return out


@lru_cache(maxsize=4)
def _load_table(path: str) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise ColorNamesNotFoundError(
            f"ARCF-HC needs the Color Names table 'cn_norm_32768x10.npy' (float32, 32768x10, "
            f"the normalised CNnorm table of van de Weijer et al. 2009, "
            f"SHA-256 {CN_SHA256[:16]}...)"
            f" but it is not at {p}. Point to it with the environment variable {COLORNAMES_ENV}="
            f"/path/to/cn_norm_32768x10.npy, or pass colornames_path=... to create_tracker, or set "
            f"ARCF_DATA to a data root holding colornames/cn_norm_32768x10.npy. (Gray frames and "
            f"the 'arcf-h' and 'bacf' presets do not need it.)"
        )
    table = np.load(p).astype(np.float32, copy=False)
    if table.shape != (32768, 10):
        raise ColorNamesNotFoundError(
            f"{p} is not a Color Names table: expected shape (32768, 10), got {table.shape}"
        )
    return np.ascontiguousarray(table)
