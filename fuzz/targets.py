"""Fuzz targets: every parser of bytes that a client, a camera or a ROS 2 node controls, each
with the contract it keeps on any input.

A target is ``f(data: bytes) -> None``. It returns quietly when the parser either accepted the
bytes or refused them with its documented error. It raises :class:`ContractBroken` (or lets
something undocumented escape) when the parser broke its word. A memory error kills the
process: the fuzzer reports it with the input.

The targets and what they hold:

``jpeg_region``
    the C region decoder (``client/media/_jpegregion.c``), called directly. Input: 8 bytes giving
    the rectangle as fractions of the picture, then the JPEG. Holds: ``ValueError`` or a
    rectangle inside the picture that covers the request; not one byte written outside the
    returned rectangle (a guarded buffer: this catches libjpeg's own writes, which no
    sanitizer here instruments).
``image``
    a frame's picture as a worker decodes it (``decode_image``: the header check, simplejpeg,
    OpenCV, the region decoder). Input: 1 byte choosing the encoding and whether a region is
    asked for, then the payload. Holds: pixels or a documented error code, never more pixels
    than the limit (a decompression bomb refused from its header).
``message``
    the msgpack wire decoder (``arcf.schemas.decode``). Holds: a message or a
    :class:`~arcf.schemas.SchemaError`; a decoded message, encoded, decodes and encodes to
    the same bytes.
``video``
    the H.264 / H.265 access-unit parser and decoder (``nal_units``, ``StreamDecoder``,
    ``PictureSize``). Input: 1 byte choosing the codec, then up to four access units split at
    ``b"AU--"``. Holds: NAL units that are the input's own bytes in order; a decoded picture
    or a counted resync, never an exception; a size within ``max_pixels``.
``cdr``
    the ROS 2 CDR readers: ``CompressedImage`` and ``Detection2D`` (the ROS 2 bridge) and
    Foxglove's ``CompressedVideo`` (``parse_compressed_video``). Input: 1 byte choosing the
    type, then the CDR. Holds: a message or an ``Exception`` (what the bridge counts as a bad
    sample); ``parse_compressed_video`` raises only ``ValueError``.
``frame_size``
    the MAVLink camera adapter's reader of a frame's size (``frame_size``, over
    ``image_size``). Holds: a size within the limit or ``ValueError``; a JPEG whose size the
    header reader accepts has that size when libjpeg reads the header too.
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Callable
from types import SimpleNamespace

import numpy as np

#: the service's default largest picture (4096 x 2160): what a worker accepts
MAX_PIXELS = 4096 * 2160
#: canary byte around and outside a decoded rectangle
CANARY = 0xA5


class ContractBroken(AssertionError):
    """A parser did something its documentation rules out."""


def _check(condition: bool, what: str) -> None:
    if not condition:
        raise ContractBroken(what)


def _rectangle(prefix: bytes, width: int, height: int) -> tuple[int, int, int, int]:
    """(top, left, bottom, right) from 4 big-endian uint16 fractions of the picture; the
    extremes (0 and 65535) map a little outside it, which the decoder must clamp."""
    t, lf, b, r = struct.unpack(">4H", prefix)
    rows = [round(v / 65535 * (height + 16)) - 8 for v in (t, b)]
    cols = [round(v / 65535 * (width + 16)) - 8 for v in (lf, r)]
    return rows[0], cols[0], rows[1], cols[1]


def jpeg_region(data: bytes) -> None:
    from arcf.client.media import _jpegregion

    if len(data) < 8:
        return
    prefix, jpeg = data[:8], data[8:]
    try:
        width, height, components, _, _ = _jpegregion.header(jpeg)
    except ValueError:
        return
    _check(width > 0 and height > 0, f"header() gave a {width}x{height} picture")
    if components not in (1, 3) or width * height > MAX_PIXELS:
        return  # what decode_jpeg_region never asks of it
    channels = 3 if components == 3 else 1
    size, guard = width * height * channels, 64
    buffer = np.full(size + 2 * guard, CANARY, np.uint8)
    out = buffer[guard:guard + size]
    top, left, bottom, right = _rectangle(prefix, width, height)
    try:
        got = _jpegregion.decode_region(jpeg, out, top, left, bottom, right)
    except ValueError:
        _check(bool((buffer[:guard] == CANARY).all() and (buffer[-guard:] == CANARY).all()),
               "a refused decode wrote outside its buffer")
        return
    _check(bool((buffer[:guard] == CANARY).all() and (buffer[-guard:] == CANARY).all()),
           "the decode wrote outside its buffer")
    t, lf, b, r = got
    _check(0 <= t < b <= height and 0 <= lf < r <= width, f"rectangle {got} outside the "
           f"{width}x{height} picture")
    _check(t <= max(top, 0) and lf <= max(left, 0) and b >= min(bottom, height)
           and r >= min(right, width),
           f"rectangle {got} does not cover the request {(top, left, bottom, right)}")
    pixels = out.reshape(height, width, channels)
    outside = np.ones((height, width), bool)
    outside[t:b, lf:r] = False
    _check(bool((pixels[outside] == CANARY).all()), f"pixels written outside {got}")


def image(data: bytes) -> None:
    from arcf.client.media.encodings import decode_image
    from arcf.schemas import ErrorCode

    if not data:
        return
    encoding = ("jpeg", "png")[data[0] & 1]
    region = (4, 4, 40, 60) if data[0] & 2 else None
    frame = SimpleNamespace(payload=data[1:], encoding=encoding, width=None, height=None)
    pixels, error = decode_image(frame, max_pixels=MAX_PIXELS, region=region)
    if pixels is None:
        _check(error is not None and isinstance(error[0], ErrorCode) and bool(error[1]),
               f"no pixels and no documented error: {error!r}")
        return
    _check(error is None, "pixels and an error")
    shape = pixels.shape if isinstance(pixels, np.ndarray) else pixels.pixels.shape
    _check(shape[0] * shape[1] <= MAX_PIXELS, f"{shape} decoded past the {MAX_PIXELS} limit")


def message(data: bytes) -> None:
    from arcf.schemas import SchemaError, decode, encode

    try:
        decoded = decode(data)
    except SchemaError:
        return
    once = encode(decoded)  # compared as bytes: a result's box may hold NaN
    _check(encode(decode(once)) == once,
           f"{type(decoded).__name__} does not survive encode / decode")


def video(data: bytes) -> None:
    from arcf.client.media.nal import MAX_NAL_UNITS, nal_units
    from arcf.client.media.video import (
        Outcome,
        PictureSize,
        StreamDecoder,
    )

    if not data:
        return
    codec = ("h264", "hevc")[data[0] & 1]
    units = data[1:].split(b"AU--")[:4]
    decoder, size = StreamDecoder(codec, max_pixels=MAX_PIXELS), PictureSize(codec, MAX_PIXELS)
    for seq, unit in enumerate(units):
        try:
            found = nal_units(unit, codec)
        except ValueError:
            found = None
        if found is not None:
            _check(len(found) <= MAX_NAL_UNITS, f"{len(found)} NAL units")
            at = 0
            for _, piece in found:
                _check(piece.startswith((b"\x00\x00\x01", b"\x00\x00\x00\x01")),
                       "a NAL unit without its start code")
                where = unit.find(piece, at)
                _check(where >= at, "NAL units that are not the input's bytes in order")
                at = where + len(piece)
        decoded = decoder.decode(seq, unit)
        _check(isinstance(decoded.outcome, Outcome), f"outcome {decoded.outcome!r}")
        if decoded.picture is not None:
            _check(decoded.picture.width * decoded.picture.height <= MAX_PIXELS,
                   "a picture over max_pixels")
        size.feed(unit)
    read = size.read()
    _check(read is None or read[0] * read[1] <= MAX_PIXELS, f"size {read} over max_pixels")


def cdr(data: bytes) -> None:
    from arcf.adapters import ros2_types as rt
    from arcf.client.foxglove import parse_compressed_video

    if not data:
        return
    kind, payload = data[0] % 3, data[1:]
    if kind == 2:
        with contextlib.suppress(ValueError):
            parse_compressed_video(payload)
        return
    with contextlib.suppress(Exception):  # the bridge counts any as a bad sample
        rt.deserialize(payload, (rt.COMPRESSED_IMAGE, rt.DETECTION_2D)[kind])


def frame_size(data: bytes) -> None:
    from arcf.adapters.mavlink import frame_size as read_size
    from arcf.client.media import _jpegregion
    from arcf.client.media.headers import image_size

    if not data:
        return
    encoding = ("jpeg", "png")[data[0] & 1]
    frame = SimpleNamespace(payload=data[1:], encoding=encoding, width=None, height=None)
    try:
        width, height = read_size(frame, max_pixels=MAX_PIXELS)  # type: ignore[arg-type]
    except ValueError:
        return
    _check(width * height <= MAX_PIXELS, f"{width}x{height} over the limit")
    if encoding == "jpeg":
        _check(image_size(frame.payload) == (width, height), "two sizes for one header")
        try:
            declared = _jpegregion.header(frame.payload)[:2]
        except ValueError:
            return  # libjpeg refuses the picture: so will the decode
        _check(tuple(declared) == (width, height),
               f"the header reader says {width}x{height}, libjpeg {declared}")


TARGETS: dict[str, Callable[[bytes], None]] = {
    "jpeg_region": jpeg_region, "image": image, "message": message, "video": video,
    "cdr": cdr, "frame_size": frame_size}
