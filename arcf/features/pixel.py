"""Pixel-level features averaged over cells: grayscale and Color Names (ARCF-HC).

Both follow ECO's ``average_feature_region``: the mean over each cell x cell block, blocks aligned
to the top-left corner, giving a floor(H/cell) x floor(W/cell) grid like fHOG's.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from ..data import COLORNAMES_ENV, default_colornames_path
from ..errors import ColorNamesNotFoundError

CN_SHA256 = "e056387d4bc872167cfb2519693d7dce9a25d07dc3a867c5b22e86d2caf5689c"


def cell_average(maps: np.ndarray, cell: int) -> np.ndarray:
    """Mean over cell x cell blocks of (N, H, W, C) maps -> (N, H//cell, W//cell, C) float32.

    Computed as the release does (ECO's ``average_feature_region``): a float32 integral image
    (``cumsum`` down the rows, then along the columns), four corner reads per cell, divided by
    the cell area. The rounding of that running sum differs from a block mean by up to 3e-5 on a
    200x200 patch; matching it makes the grey and Color Names blocks equal to the release's bit
    for bit.
    """
    n, h, w, c = maps.shape
    hb, wb = h // cell, w // cell
    if hb == 0 or wb == 0:
        return np.zeros((n, hb, wb, c), np.float32)
    integral = np.zeros((n, hb * cell + 1, wb * cell + 1, c), np.float32)
    inner = integral[:, 1:, 1:]
    np.cumsum(maps[:, : hb * cell, : wb * cell], axis=1, dtype=np.float32, out=inner)
    np.cumsum(inner, axis=2, out=inner)
    corners = integral[:, ::cell, ::cell]  # (N, hb + 1, wb + 1, C)
    sums = corners[:, 1:, 1:] - corners[:, 1:, :-1] - corners[:, :-1, 1:] + corners[:, :-1, :-1]
    return sums / np.float32(cell * cell)


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
        return cell_average(self.table[index], cell)


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
