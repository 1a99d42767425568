"""Pixel-level features averaged over cells: grayscale and Color Names (ARCF-HC).

Both follow ECO's ``average_feature_region``: the mean over each cell x cell block, blocks aligned
to the top-left corner, giving a floor(H/cell) x floor(W/cell) grid like fHOG's.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from ..data import COLORNAMES_ENV, default_colornames_path
from ..errors import ColorNamesNotFoundError

CN_SHA256 = "e056387d4bc872167cfb2519693d7dce9a25d07dc3a867c5b22e86d2caf5689c"


def cell_average(maps: np.ndarray, cell: int) -> np.ndarray:
    """Mean over cell x cell blocks of (N, H, W, C) maps -> (N, H//cell, W//cell, C)."""
    n, h, w, c = maps.shape
    hb, wb = h // cell, w // cell
    cropped = maps[:, : hb * cell, : wb * cell]
    return cropped.reshape(n, hb, cell, wb, cell, c).mean(axis=(2, 4), dtype=np.float32)


def gray_features(patches: np.ndarray, cell: int) -> np.ndarray:
    """Grayscale channel: gray/255 - 0.5, averaged per cell. (N, H, W, 1|3) uint8 -> (N, h, w, 1).

    Colour patches are converted like MATLAB's ``rgb2gray`` (ITU-R 601 weights, rounded to uint8).
    """
    if patches.shape[-1] == 3:
        gray = np.stack([cv2.cvtColor(p, cv2.COLOR_BGR2GRAY) for p in patches])[..., None]
    else:
        gray = patches
    g = gray.astype(np.float32) * np.float32(1.0 / 255.0) - np.float32(0.5)
    return cell_average(g, cell)


class ColorNames:
    """The 32768 x 10 Color Names lookup (van de Weijer et al. 2009), normalised (``CNnorm``).

    The table is data we may not redistribute, so it is loaded from a path: the argument, else
    ``$ARCF_COLORNAMES``, else ``<data root>/colornames/cn_norm_32768x10.npy``.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else default_colornames_path()
        self.table = _load_table(str(self.path.resolve()) if self.path.exists() else str(self.path))

    def __call__(self, patches: np.ndarray, cell: int) -> np.ndarray:
        """(N, H, W, 3) BGR uint8 -> (N, H//cell, W//cell, 10) float32."""
        p = patches.astype(np.int32) >> 3
        index = p[..., 2] + 32 * p[..., 1] + 1024 * p[..., 0]  # R//8 + 32 G//8 + 1024 B//8
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
