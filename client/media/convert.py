"""A decoded video picture as the BGR pixels the trackers read: the whole picture, or only the
region they read (``arcf.region``).

Cameras send 4:2:0 YCbCr (``yuv420p``) with BT.601 or unspecified colours in the video range:
OpenCV converts it (``COLOR_YUV2BGR_I420``), each 2x2 block of pixels from its own chroma
sample, so a region cut on even rows and columns converts to exactly the pixels of the whole
picture's conversion (tests/service/test_region_decode.py) and costs its share of them. Other
pictures (full range, BT.709, 4:2:2, 10 bits, ...) go through FFmpeg's swscale, which knows
their colours, whole.

The library reference of the load tools (``arcf.loadtools.video.decode_video``) converts with
``picture_bgr`` too, so that "the library alone" sees the pixels a worker tracks.
"""

from __future__ import annotations

import av
import cv2
import numpy as np

from arcf.region import Region, RegionFrame, area

#: FFmpeg's colour spaces (AVColorSpace) whose colours are BT.601's: unspecified (2),
#: BT.470BG (5), SMPTE 170M (6); and ranges: unspecified (0), video / MPEG (1)
_BT601_SPACES = frozenset({2, 5, 6})
_VIDEO_RANGES = frozenset({0, 1})
#: A region larger than this share of the picture is converted whole.
REGION_MAX_SHARE = 0.5


def _planes(picture: av.VideoFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Y (H, W), U and V (H/2, W/2) views of a yuv420p picture's planes (no copy)."""
    h, w = picture.height, picture.width
    out = []
    for plane, (ph, pw) in zip(picture.planes, ((h, w), ((h + 1) // 2, (w + 1) // 2),
                                                ((h + 1) // 2, (w + 1) // 2)), strict=True):
        rows = np.frombuffer(memoryview(plane), np.uint8).reshape(-1, plane.line_size)
        out.append(rows[:ph, :pw])
    return out[0], out[1], out[2]


def converts_by_region(picture: av.VideoFrame) -> bool:
    """Whether the picture is one OpenCV converts exactly by regions (4:2:0 BT.601 video
    range, even sizes)."""
    return (picture.format.name == "yuv420p" and picture.colorspace in _BT601_SPACES
            and picture.color_range in _VIDEO_RANGES
            and picture.width % 2 == 0 and picture.height % 2 == 0)


def _convert(y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """OpenCV's I420 -> BGR of one even-sized block of planes, (h, w, 3)."""
    h, w = y.shape
    packed = np.empty(h * w * 3 // 2, np.uint8)
    packed[:h * w] = y.ravel()
    packed[h * w:h * w * 5 // 4] = u.ravel()
    packed[h * w * 5 // 4:] = v.ravel()
    return cv2.cvtColor(packed.reshape(h * 3 // 2, w), cv2.COLOR_YUV2BGR_I420)


def picture_bgr(picture: av.VideoFrame) -> np.ndarray:
    """The whole picture as (H, W, 3) uint8 BGR."""
    if converts_by_region(picture):  # PyAV packs the planes as OpenCV's I420 layout
        return cv2.cvtColor(picture.to_ndarray(), cv2.COLOR_YUV2BGR_I420)
    return picture.to_ndarray(format="bgr24")


def picture_bgr_region(picture: av.VideoFrame, region: Region | None
                       ) -> np.ndarray | RegionFrame:
    """The picture's pixels inside ``region`` (widened to even rows and columns) in a
    frame-sized array, the whole picture on demand; the whole picture where the region is
    None, large, or the picture is not one converted by regions."""
    if (region is None or not converts_by_region(picture)
            or area(region) > REGION_MAX_SHARE * picture.width * picture.height):
        return picture_bgr(picture)
    y, u, v = _planes(picture)
    t, lf = region[0] & ~1, region[1] & ~1
    b, r = min(region[2] + 1, picture.height) & ~1, min(region[3] + 1, picture.width) & ~1
    pixels = np.empty((picture.height, picture.width, 3), np.uint8)
    pixels[t:b, lf:r] = _convert(y[t:b, lf:r], u[t // 2:b // 2, lf // 2:r // 2],
                                 v[t // 2:b // 2, lf // 2:r // 2])
    return RegionFrame(pixels, (t, lf, b, r), lambda: picture_bgr(picture))
