"""Partial JPEG decompression (client/media/_jpegregion.c): libjpeg-turbo's jpeg_skip_scanlines and
jpeg_crop_scanline."""

import numpy as np
from typing_extensions import Buffer

LIBJPEG_TURBO_VERSION: int

def decode_region(data: Buffer, out: Buffer | np.ndarray, top: int, left: int, bottom: int,
                  right: int, /) -> tuple[int, int, int, int]: ...
def header(data: Buffer, /) -> tuple[int, int, int, int, int]: ...
def seek(data: Buffer, top: int, left: int, bottom: int, right: int, /
         ) -> tuple[int, int] | None: ...
