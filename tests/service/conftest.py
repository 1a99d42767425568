"""What the server's tests share: payloads a hostile (or merely broken) ground station sends,
and the short real clip the stations replay."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from typing import Any

import pytest

from arcf.loadtools.driver import Clip


def _png_bomb(width: int, height: int) -> bytes:
    """A valid grayscale PNG of width x height zeros: tiny on the wire, huge decoded (a
    decompression bomb: 10000 x 10000 is 100 MB of pixels in about 100 KB)."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    comp = zlib.compressobj(9)
    row = b"\x00" * (width + 1)  # filter byte + pixels
    idat = b"".join(comp.compress(row) for _ in range(height)) + comp.flush()
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat)
            + chunk(b"IEND", b""))


@pytest.fixture
def png_bomb() -> Callable[[int, int], bytes]:
    """``png_bomb(width, height)``: a valid PNG of that many zero pixels, tiny on the wire."""
    return _png_bomb


@pytest.fixture(scope="module")
def clip(wakeboard7: Any) -> Clip:
    """wakeboard7's first 40 frames as a station replays them: a real stream long enough for
    the attacks and the budget tests, loaded once per module (a module that needs another
    length defines its own ``clip``)."""
    return Clip.of(wakeboard7, limit=40)
