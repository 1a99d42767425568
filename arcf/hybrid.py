"""ARCF beside a Siamese network: the network's box, ARCF's aberrance, state and re-detection.

What each half brings. A Siamese network (NanoTrack v2, :mod:`arcf.siamese`), trained offline
on large tracking datasets, regresses a tighter box than a correlation filter, but it cannot
say when it has lost its target (its score hardly moves) and it only looks near its last box.
ARCF's filter, learnt online on this target and its background, can: its response collapses
when the target is hidden, and its whole-frame search finds it again (:mod:`arcf.state`,
:mod:`arcf.reacquire`). Per frame:

1. the network tracks: its box is the result's box;
2. the filter is steered onto that box (:meth:`arcf.tracker.ARCFTracker.steer`) and runs one
   ordinary ARCF step there: its response at the network's box gives the peak, PSR, the
   aberrance of Eq. 2, the state and the confidence; it learns only while ``tracking``, so it
   keeps the look of the target, not of what the network may have drifted onto;
3. once the track is ``lost``, the filter's search runs over the whole frame; a place it
   confirms farther than ``restart_distance`` target sizes from the network's box restarts the
   network there (the result says ``reacquired`` and carries that box). A network that finds
   the target again by itself brings the filter's response back at its box: the track resumes
   in place, nothing is restarted.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from .presets import HybridParams, SiameseParams
from .region import Region, RegionFrame, whole_frame
from .siamese import SiameseTracker
from .state import StateParams, TrackState
from .tracker import ARCFTracker
from .types import Box, TrackResult


def _centre(box: Box) -> tuple[float, float]:
    return box[0] + box[2] / 2, box[1] + box[3] / 2


class HybridTracker:
    """The ``arcf-nano`` preset (:class:`~arcf.presets.HybridParams`): ``init(frame, box)``,
    ``update(frame) -> TrackResult``."""

    def __init__(self, params: HybridParams, models_dir: str | Path | None = None,
                 colornames_path: str | Path | None = None) -> None:
        self.params = params
        network = SiameseParams(name=f"{params.name}.network", network=params.network,
                                state=StateParams(reacquire=False))
        self.network = SiameseTracker(network, models_dir)
        self.verifier = ARCFTracker(params.verifier, colornames_path)
        #: network restarts by the filter's search, since the last init
        self.restarts = 0
        self._side0 = 1.0
        self._agreeing = 0

    @property
    def initialized(self) -> bool:
        return self.network.initialized and self.verifier.initialized

    def init(self, frame: np.ndarray, box: Box | Any) -> TrackResult:
        """Start both halves on ``box``; the filter first (it validates frame and box), the
        network second: a failed start of either leaves the running track as it was."""
        previous = (self.verifier._layout, self.verifier._state)
        first = self.verifier.init(frame, box)
        try:
            self.network.init(frame, box)
        except BaseException:
            self.verifier._layout, self.verifier._state = previous
            raise
        self.restarts, self._agreeing = 0, 0
        given = tuple(float(v) for v in box)
        self._side0 = math.sqrt(given[2] * given[3])
        return TrackResult(box=(given[0], given[1], given[2], given[3]), peak=first.peak,
                           psr=first.psr, aberrance=0.0, aberrance_release=0.0, scale=1.0,
                           frame_index=0)

    def _agreement(self, checked: TrackResult, seen: TrackResult) -> None:
        """Count the frames on which the network and the filter agree on a track the filter
        no longer trusts (``HybridParams.agree_*``); enough of them resume it."""
        p = self.params
        if checked.state is TrackState.TRACKING:
            self._agreeing = 0
            return
        reach = p.agree_distance * max(seen.box[2], seen.box[3])
        agree = (self.network.strength >= p.agree_score
                 and self.verifier.strength >= p.verifier.state.coast_below
                 and math.dist(_centre(checked.box), _centre(seen.box)) <= reach)
        self._agreeing = self._agreeing + 1 if agree else 0
        if self._agreeing >= p.agree_frames:
            self.verifier.resume()
            self._agreeing = 0

    def read_region(self) -> Region | None:
        """None: the network reads the whole frame."""
        return None

    def update(self, frame: np.ndarray | RegionFrame) -> TrackResult:
        frame = whole_frame(frame)
        seen = self.network.update(frame)
        self.verifier.steer(seen.box)
        checked = self.verifier.update(frame)
        box = seen.box
        self._agreement(checked, seen)
        if checked.reacquired and checked.state is TrackState.TRACKING:
            size = max(checked.box[2], checked.box[3])
            if math.dist(_centre(checked.box), _centre(seen.box)) > (
                    self.params.restart_distance * size):
                self.network.init(frame, checked.box)
                self.restarts += 1
                box = checked.box
        return TrackResult(
            box=box, peak=checked.peak, psr=checked.psr, aberrance=checked.aberrance,
            aberrance_release=checked.aberrance_release,
            scale=math.sqrt(box[2] * box[3]) / self._side0,
            frame_index=checked.frame_index, confidence=checked.confidence,
            state=checked.state, reacquired=checked.reacquired)
