"""JPEG and PNG pictures decoded: whole (``decode_compressed``, as a worker decodes them, and
so the load tools' library reference and the benchmarks too, so that "the library alone"
decodes exactly as a worker does), or a JPEG by region (``decode_jpeg_region``). The checks
that come first (size limits, error codes) are the encoding table's (:mod:`.encodings`).

Given the region its trackers read (``arcf.region``), a worker decodes a JPEG only there
(``decode_jpeg_region``): libjpeg-turbo's partial decompression through the small C module
``_jpegregion``. Its pixels equal the whole decode's from 8 pixels inside the decoded
rectangle's edges on (the triangle upsampling of the edge's chroma sees no neighbour there;
tests/service/test_region_decode.py), so the rectangle asked for is the region widened by that.
"""

from __future__ import annotations

from types import ModuleType

import cv2
import numpy as np
import simplejpeg

from arcf.region import Region, RegionFrame, area

_jpegregion: ModuleType | None
try:
    from . import _jpegregion
except ImportError:  # not built (no compiler or libjpeg headers at install): whole pictures
    _jpegregion = None

#: Pixels by which a partially decoded rectangle's edges differ from the whole decode's.
REGION_EDGE = 8
#: A region larger than this share of the picture is decoded whole: the partial decode reads
#: every row above the region's bottom anyway, and a frame that goes lost needs the rest.
REGION_MAX_SHARE = 0.5
#: Whether this install decodes JPEG regions (the C module was built).
REGION_DECODING = _jpegregion is not None


def decode_compressed(payload: bytes) -> np.ndarray:
    """JPEG or PNG bytes as uint8 BGR ``(H, W, 3)`` or grey ``(H, W)`` pixels, as a worker
    decodes them (simplejpeg for YCbCr / grey JPEG, OpenCV for the rest; deeper PNGs scaled
    to 8 bits, alpha dropped). Raises ``ValueError`` when the bytes are not an image."""
    image = _decode_jpeg(payload)
    if image is not None:
        return image
    try:
        image = cv2.imdecode(np.frombuffer(payload, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:  # e.g. an empty buffer: OpenCV asserts instead of failing
        raise ValueError(str(exc).strip().splitlines()[-1]) from exc
    if image is None:
        raise ValueError("not a decodable image")
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


def _decode_jpeg(payload: bytes) -> np.ndarray | None:
    """A YCbCr (colour) or grey JPEG decoded by simplejpeg, or None to leave it to OpenCV.

    Why: both wrap libjpeg-turbo with its default (accurate) IDCT and upsampling and give the
    same pixels (tests/service/test_imagecheck.py), but simplejpeg decodes the benchmark's 1280x720
    frames in 2.0 ms where ``cv2.imdecode`` takes 4.7 (docs/service-design.md, "Decoding"), a
    third of a tracked frame's cost. Anything else (CMYK, a header or stream simplejpeg refuses,
    truncated data) goes to ``cv2.imdecode`` as before, which decodes it or reports it.
    """
    try:
        colorspace = simplejpeg.decode_jpeg_header(payload)[2]
        if colorspace == "YCbCr":
            return simplejpeg.decode_jpeg(payload, colorspace="BGR")
        if colorspace == "Gray":
            return simplejpeg.decode_jpeg(payload, colorspace="GRAY")[..., 0]
    except (ValueError, TypeError, KeyError):  # refused: OpenCV decides
        # KeyError: simplejpeg's header reader meets a colour space it has no name for (found
        # by fuzzing: fuzz/seeds.py, FOUND)
        pass
    return None


def decode_jpeg_region(payload: bytes, region: Region) -> RegionFrame | None:
    """The JPEG's pixels inside ``region`` (at least), in a frame-sized array, the whole
    picture on demand; None where a partial decode does not apply (no C module, a region over
    ``REGION_MAX_SHARE`` of the picture, a picture the module does not take, damage: the
    caller decodes the whole picture, which reports what is wrong)."""
    # a picture cut short (no end marker) is left to the whole decode, which refuses it even
    # where the cut lies below the region
    if _jpegregion is None or not payload.endswith(b"\xff\xd9"):
        return None
    try:
        width, height, components, _, _ = _jpegregion.header(payload)
    except ValueError:
        return None
    if components not in (1, 3) or area(region) > REGION_MAX_SHARE * width * height:
        return None
    shape = (height, width, 3) if components == 3 else (height, width)
    pixels = np.empty(shape, np.uint8)
    t, lf, b, r = region
    e = REGION_EDGE
    try:
        got = _jpegregion.decode_region(payload, pixels, t - e, lf - e, b + e, r + e)
    except ValueError:
        return None
    # the decoded rectangle's own edges (inside the picture) are the upsampler's guesses
    exact = (got[0] + e if got[0] > 0 else 0, got[1] + e if got[1] > 0 else 0,
             got[2] - e if got[2] < height else height, got[3] - e if got[3] < width else width)
    return RegionFrame(pixels, exact, lambda: decode_compressed(payload))
