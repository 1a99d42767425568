"""The wire's encodings, one table: for each, how its size is read, how it is decoded (whole or
by region), how pixels are encoded into it, and, for video, FFmpeg's names and the NAL unit
types that matter.

Everything that reads or writes a frame's payload goes through this table: the service's
workers (:func:`decode_image`, with their size limit and error codes), the client SDK
(:func:`encode_image`), and the adapters (the MAVLink camera's size reading, the live view's
and the recorder's pictures). A new encoding is one :class:`Codec` entry here, beside its
value in :class:`arcf.schemas.Encoding` (what the wire accepts), and its tests.

Three kinds of encoding:

- ``image``: one compressed picture per frame (JPEG, PNG); the size is read from the header
  before anything is decoded, so a decompression bomb is refused for free;
- ``raw``: row-major 8-bit pixels, the size declared in the frame (checked by the schema);
- ``video``: one access unit of a stream (H.264, H.265), decoded in order by one stateful
  decoder per stream (:class:`~.video.StreamDecoder`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Literal

import cv2
import numpy as np

from arcf.region import Region, RegionFrame
from arcf.schemas import Encoding, ErrorCode

from .headers import image_size
from .images import decode_compressed, decode_jpeg_region
from .nal import KEYFRAME_TYPES, PARAMETER_TYPES, nal_units

if TYPE_CHECKING:  # PyAV (FFmpeg) loads with the first video decoder, not with the table
    from .video import PictureSize, StreamDecoder

Kind = Literal["image", "raw", "video"]
#: pixels (uint8 BGR or grey) and a quality (0-100, where the encoding is lossy) -> bytes
Encoder = Callable[[np.ndarray, int], bytes]


def restart_interval(image: np.ndarray) -> int:
    """The restart interval, in MCUs, a JPEG of ``image`` is written with: the smallest
    divisor of a row's MCU count that is at least 8 (128 pixels of OpenCV's 4:2:0 colour,
    64 of grey), or the whole row. Intervals that tile the MCU grid let a decoder that needs
    only a region read just the intervals covering it (``_jpegregion``'s restart seek: a
    worker decodes a 720p frame's tracked region in about 0.4 ms wherever it lies, against
    0.8 to 2 ms from the picture's top); the markers cost about 1 % of the bytes."""
    mcu = 16 if image.ndim == 3 and image.shape[2] == 3 else 8
    per_row = -(-image.shape[1] // mcu)
    return next((d for d in range(8, per_row) if per_row % d == 0), per_row)


def _imencode(extension: str, flags: Callable[[np.ndarray, int], list[int]]) -> Encoder:
    def encode(image: np.ndarray, quality: int) -> bytes:
        ok, buf = cv2.imencode(extension, image, flags(image, quality))
        if not ok:
            raise ValueError(f"the image could not be encoded as {extension[1:]}")
        return bytes(buf.tobytes())
    return encode


def _raw(image: np.ndarray, quality: int) -> bytes:
    return bytes(np.ascontiguousarray(image).tobytes())


@dataclass(frozen=True)
class Codec:
    """One wire encoding and every operation on its payloads."""

    encoding: Encoding
    kind: Kind
    #: ``image``: (width, height) from the header, None when it cannot be read
    read_size: Callable[[bytes], tuple[int, int] | None] | None = None
    #: ``image``: the whole picture, uint8 BGR or grey; ``ValueError`` when not decodable
    decode: Callable[[bytes], np.ndarray] | None = None
    #: the pixels of one region only (a :class:`~arcf.region.RegionFrame`), or None to
    #: decode the whole picture instead
    decode_region: Callable[[bytes, Region], RegionFrame | None] | None = None
    #: pixels -> payload (the SDK's senders, the recorder)
    encode: Encoder | None = None
    #: ``video``: FFmpeg's decoder (PyAV's codec name) and the encoder the load tools use
    ffmpeg: str | None = None
    ffmpeg_encoder: str | None = None

    @property
    def is_video(self) -> bool:
        return self.kind == "video"

    @property
    def channels(self) -> int | None:
        """Bytes per pixel of a raw encoding (the wire contract's), None otherwise."""
        return self.encoding.channels

    @property
    def keyframe_types(self) -> frozenset[int]:
        """NAL unit types that start a decodable picture (IDR; H.265's IRAP)."""
        return KEYFRAME_TYPES[self.decoder_name]

    @property
    def parameter_types(self) -> frozenset[int]:
        """NAL unit types of the parameter sets (SPS/PPS; and VPS for H.265)."""
        return PARAMETER_TYPES[self.decoder_name]

    def nal_units(self, unit: bytes) -> list[tuple[int, bytes]]:
        """An access unit's NAL units, (type, bytes); ``ValueError`` past the bound."""
        return nal_units(unit, self.decoder_name)

    def is_keyframe(self, unit: bytes) -> bool:
        return any(kind in self.keyframe_types for kind, _ in self.nal_units(unit))

    def stream_decoder(self, max_pixels: int = 8_847_360,
                       history_units: int = 0) -> StreamDecoder:
        """A fresh decoder for one stream of this encoding's access units (keeping up to
        ``history_units`` of its group of pictures, for ``replay``)."""
        from .video import StreamDecoder

        return StreamDecoder(self.decoder_name, max_pixels, history_units)

    def size_reader(self, max_pixels: int = 8_847_360) -> PictureSize:
        """A stream's picture size from its keyframes, without decoding every unit."""
        from .video import PictureSize

        return PictureSize(self.decoder_name, max_pixels)

    @property
    def decoder_name(self) -> str:
        """FFmpeg's decoder of a video encoding; ``ValueError`` for a picture encoding."""
        if self.ffmpeg is None:
            raise ValueError(f"{self.encoding.value} is not a video encoding")
        return self.ffmpeg

    @property
    def encoder_name(self) -> str:
        """FFmpeg's encoder of a video encoding; ``ValueError`` for a picture encoding."""
        if self.ffmpeg_encoder is None:
            raise ValueError(f"{self.encoding.value} is not a video encoding")
        return self.ffmpeg_encoder


#: Every encoding of the wire contract.
ENCODINGS: Mapping[Encoding, Codec] = MappingProxyType({c.encoding: c for c in (
    Codec(Encoding.JPEG, "image", read_size=image_size, decode=decode_compressed,
          decode_region=decode_jpeg_region,
          encode=_imencode(".jpg", lambda image, q: [cv2.IMWRITE_JPEG_QUALITY, q,
                                                     cv2.IMWRITE_JPEG_RST_INTERVAL,
                                                     restart_interval(image)])),
    Codec(Encoding.PNG, "image", read_size=image_size, decode=decode_compressed,
          encode=_imencode(".png", lambda image, q: [])),
    Codec(Encoding.BGR8, "raw", encode=_raw),
    Codec(Encoding.GRAY8, "raw", encode=_raw),
    Codec(Encoding.H264, "video", ffmpeg="h264", ffmpeg_encoder="libx264"),
    Codec(Encoding.H265, "video", ffmpeg="hevc", ffmpeg_encoder="libx265"),
)})

#: The video encodings' names (command-line choices, say).
VIDEO_ENCODINGS: tuple[str, ...] = tuple(e.value for e, c in ENCODINGS.items() if c.is_video)


def codec_of(encoding: Encoding | str) -> Codec:
    """The table's entry for an encoding (its enum or its wire name); ``ValueError`` for a
    name the wire does not have."""
    try:
        return ENCODINGS[Encoding(encoding)]
    except ValueError:
        raise ValueError(f"unknown encoding {encoding!r}; the wire has "
                         f"{', '.join(e.value for e in ENCODINGS)}") from None


def video_codec(name: str) -> Codec | None:
    """The video encoding of a wire name (a frame's ``encoding``, a CompressedVideo's
    ``format``), or None where the name is no video encoding of the wire."""
    try:
        codec = ENCODINGS[Encoding(name)]
    except ValueError:
        return None
    return codec if codec.is_video else None


def encode_image(image: np.ndarray, encoding: Encoding | str = "jpeg", quality: int = 90
                 ) -> bytes:
    """Pixels as a payload of a picture encoding (not video: a stream's encoder is stateful)."""
    codec = codec_of(encoding)
    if codec.encode is None:
        raise ValueError(f"{codec.encoding.value} payloads are not encoded one picture at a "
                         "time")
    return codec.encode(image, quality)


def decode_image(frame: Any, max_pixels: int | None = None, region: Region | None = None
                 ) -> tuple[np.ndarray | RegionFrame | None, tuple[ErrorCode, str] | None]:
    """A picture frame's pixels as uint8 BGR or grey, or (None, (error code, message)), as a
    worker decodes it; with a ``region``, a JPEG's may come as a
    :class:`~arcf.region.RegionFrame` holding it. ``frame`` has ``encoding``, ``payload``
    and, for raw pixels, ``width`` and ``height`` (a wire ``Frame``, say).

    Compressed pictures are sized from their header first: more than ``max_pixels`` is
    refused before the decoder allocates anything (a decompression bomb costs nothing)."""
    codec = codec_of(frame.encoding)
    name = codec.encoding.value
    if codec.kind == "image":
        assert codec.read_size is not None and codec.decode is not None
        if max_pixels is not None:
            size = codec.read_size(frame.payload)
            if size is None:
                return None, (ErrorCode.DECODE_ERROR, f"not a readable {name} header")
            if size[0] * size[1] > max_pixels:
                return None, (ErrorCode.IMAGE_TOO_LARGE,
                              f"{name} declares {size[0]}x{size[1]} = "
                              f"{size[0] * size[1]} pixels; the limit is {max_pixels}")
        if region is not None and codec.decode_region is not None:
            partial = codec.decode_region(frame.payload, region)
            if partial is not None:
                return partial, None
        try:
            return codec.decode(frame.payload), None
        except ValueError as exc:
            return None, (ErrorCode.DECODE_ERROR, f"cannot decode {name} frame: {exc}")
    if codec.kind == "raw":
        if frame.width is None or frame.height is None:
            return None, (ErrorCode.DECODE_ERROR, f"{name} frames need width and height")
        if max_pixels is not None and frame.width * frame.height > max_pixels:
            return None, (ErrorCode.IMAGE_TOO_LARGE,
                          f"{frame.width}x{frame.height} exceeds {max_pixels} pixels")
        channels = codec.channels or 1
        if len(frame.payload) != frame.width * frame.height * channels:
            return None, (ErrorCode.DECODE_ERROR,
                          f"{name} payload is {len(frame.payload)} bytes, expected "
                          f"{frame.width * frame.height * channels}")
        image = np.frombuffer(frame.payload, dtype=np.uint8).reshape(
            frame.height, frame.width, channels)
        return (image if channels == 3 else image[..., 0]), None
    return None, (ErrorCode.DECODE_ERROR,
                  f"{name} units are decoded by their stream's decoder, not one at a time")
