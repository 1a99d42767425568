"""Run a tracker over a sequence of frames: the one-pass loop shared by the CLI and benchmarks."""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from .tracker import ARCFTracker, Box, TrackResult


@dataclass
class SequenceRun:
    """Per-frame outputs of one pass; ``times`` are tracker seconds (no image decoding)."""

    results: list[TrackResult] = field(default_factory=list)
    times: list[float] = field(default_factory=list)

    @property
    def boxes(self) -> np.ndarray:
        return np.array([r.box for r in self.results], dtype=np.float64).reshape(-1, 4)

    @property
    def fps(self) -> float:
        total = sum(self.times)
        return len(self.times) / total if total > 0 else float("nan")


def track_frames(
    tracker: ARCFTracker, frames: Iterable[np.ndarray], init_box: Box
) -> Iterator[tuple[TrackResult, float]]:
    """Yield (result, seconds) per frame: ``init`` on the first frame, ``update`` afterwards."""
    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        return
    t0 = time.perf_counter()
    result = tracker.init(first, init_box)
    yield result, time.perf_counter() - t0
    for frame in it:
        t0 = time.perf_counter()
        result = tracker.update(frame)
        yield result, time.perf_counter() - t0


def run_sequence(tracker: ARCFTracker, frames: Iterable[np.ndarray], init_box: Box) -> SequenceRun:
    """One-pass evaluation of a whole sequence (OPE: init on the first frame, never re-init)."""
    run = SequenceRun()
    for result, seconds in track_frames(tracker, frames, init_box):
        run.results.append(result)
        run.times.append(seconds)
    return run
