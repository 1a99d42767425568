"""Re-acquisition: where a lost track looks for its target, frame after frame.

A correlation filter only looks inside its search window, so once the target has left the
window (an occlusion long enough for the camera or the target to move, a fast pan, an
out-of-view exit) no amount of waiting brings it back. While the track is ``lost``
(:mod:`arcf.state`), the tracker keeps its last trusted appearance model (no learning) and,
besides its usual detection where the box is, probes a few more windows each frame, at the
track's scale, on a grid around the position where the target was last tracked. The searched
disc grows with the time since the loss until it covers the whole frame, and the probes cycle
through it nearest first, so the cost of a lost frame is bounded by ``probes`` extra
single-scale windows, whatever the frame's size.

A probe wins when its response gives a confidence at or above the state machine's
``resume_above`` and above the box's own by ``reacquire_margin``: the box jumps there, the
track is ``tracking`` again
and the result says ``reacquired``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: (row, col) in the datasets' 1-based pixel frame
Point = tuple[float, float]


@dataclass
class Search:
    """The probe schedule of one loss (a new loss starts a new search).

    ``centre`` is where the target was last tracked; ``window`` the side of a search window in
    source pixels; probe centres lie on a grid of pitch ``spacing * window`` centred there,
    within the frame, ordered by distance (nearest first, so that a target hidden where it
    vanished is found first).
    """

    centre: Point
    window: float
    image_hw: tuple[int, int]
    #: windows probed per frame
    probes: int
    #: radius of the searched disc at the loss, and its growth per frame, in windows
    radius: float = 1.0
    growth: float = 0.25
    #: probe pitch as a fraction of the window side (half a window: every place of the frame
    #: is near the centre of some probe, where the cosine window does not hide it)
    spacing: float = 0.5
    frames: int = 0
    _cursor: int = 0

    def __post_init__(self) -> None:
        rows, cols = self.image_hw
        pitch = max(self.spacing * self.window, 1.0)
        r0, c0 = self.centre
        # grid offsets reaching every border from the centre, kept inside the frame
        i_lo, i_hi = -math.ceil((r0 - 1) / pitch), math.ceil((rows - r0) / pitch)
        j_lo, j_hi = -math.ceil((c0 - 1) / pitch), math.ceil((cols - c0) / pitch)
        points = []
        for i in range(i_lo, i_hi + 1):
            for j in range(j_lo, j_hi + 1):
                r = min(max(r0 + i * pitch, 1.0), float(rows))
                c = min(max(c0 + j * pitch, 1.0), float(cols))
                points.append((math.hypot(i, j) * pitch, math.atan2(i, j), (r, c)))
        points.sort()
        #: every probe centre with its distance from ``centre``, nearest first
        self._points: list[tuple[float, Point]] = [(d, p) for d, _, p in points]

    @property
    def candidates(self) -> int:
        """Probe centres over the whole frame: one full sweep takes ``candidates / probes``
        frames once the disc covers the frame."""
        return len(self._points)

    def radius_px(self) -> float:
        """The searched disc's radius on the current frame, source pixels."""
        return self.window * (self.radius + self.growth * self.frames)

    def next_probes(self) -> list[Point]:
        """The windows to probe on the next frame: the next ``probes`` centres within the
        disc, cycling back to the nearest once all were visited."""
        self.frames += 1
        reach = self.radius_px()
        eligible = 1
        while eligible < len(self._points) and self._points[eligible][0] <= reach:
            eligible += 1
        chosen = []
        for _ in range(min(self.probes, eligible)):
            if self._cursor >= eligible:
                self._cursor = 0
            chosen.append(self._points[self._cursor][1])
            self._cursor += 1
        return chosen
