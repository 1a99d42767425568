"""Frames decoded only where the tracker reads them.

A correlation filter reads a window a few times the target's size around its last position: on
a small target a few percent of a 1280x720 picture. A caller that decodes frames (the service)
asks the tracker which pixels its next ``update`` reads (``ARCFTracker.read_region``), decodes
those, and hands over a :class:`RegionFrame`: a frame-sized array whose pixels are the picture's
inside ``region`` and undefined outside, with a way to get the whole picture should the update
turn out to need it (a track judged lost mid-frame searches the whole frame).

A region is ``(top, left, bottom, right)`` in array indices, half-open, inside the frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

#: (top, left, bottom, right) array indices, half-open, inside the frame
Region = tuple[int, int, int, int]


def clip_region(top: float, left: float, bottom: float, right: float,
                image_hw: tuple[int, int]) -> Region:
    """The pixel rectangle covering ``[top, bottom) x [left, right)``, clipped to the frame
    (a window sticking out of the frame reads the frame's border pixels instead)."""
    rows, cols = image_hw
    t = min(max(int(np.floor(top)), 0), rows - 1)
    lf = min(max(int(np.floor(left)), 0), cols - 1)
    b = max(min(int(np.ceil(bottom)), rows), t + 1)
    r = max(min(int(np.ceil(right)), cols), lf + 1)
    return t, lf, b, r


def cover(regions: Iterable[Region | None]) -> Region | None:
    """The smallest region holding all ``regions``; None (the whole frame) if any is None or
    there are none."""
    out: Region | None = None
    for r in regions:
        if r is None:
            return None
        out = r if out is None else (min(out[0], r[0]), min(out[1], r[1]),
                                     max(out[2], r[2]), max(out[3], r[3]))
    return out


def contains(outer: Region, inner: Region) -> bool:
    return (outer[0] <= inner[0] and outer[1] <= inner[1]
            and outer[2] >= inner[2] and outer[3] >= inner[3])


def area(region: Region) -> int:
    return (region[2] - region[0]) * (region[3] - region[1])


class RegionFrame:
    """A frame of which only ``region`` holds the picture's pixels.

    ``pixels`` is ``(H, W, 3)`` BGR or ``(H, W)`` grey uint8, the whole frame's shape; outside
    ``region`` its values are undefined. ``whole()`` returns the complete picture, made once by
    ``complete`` (e.g. decoding the rest) the first time it is asked for."""

    __slots__ = ("_complete", "_whole", "pixels", "region")

    def __init__(self, pixels: np.ndarray, region: Region,
                 complete: Callable[[], np.ndarray]) -> None:
        self.pixels = pixels
        self.region = region
        self._complete = complete
        self._whole: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.pixels.shape)

    def whole(self) -> np.ndarray:
        if self._whole is None:
            self._whole = self._complete()
        return self._whole


def whole_frame(frame: np.ndarray | RegionFrame) -> np.ndarray:
    """The complete picture of ``frame`` (for trackers that read all of it)."""
    return frame.whole() if isinstance(frame, RegionFrame) else frame
