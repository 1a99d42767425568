"""Run a tracker over a sequence of frames: the one loop shared by the CLI, the evaluation runner,
the load tools and the benchmarks."""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .types import Box, Tracker, TrackResult


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


class Step(NamedTuple):
    """One frame of a pass: the frame, the tracker's result on it and the tracker's seconds."""

    frame: np.ndarray
    result: TrackResult
    seconds: float


def track_frames(
    tracker: Tracker, frames: Iterable[np.ndarray], init_box: Box
) -> Iterator[Step]:
    """The one tracking loop: ``init`` on the first frame, ``update`` on every later one.

    Yields a :class:`Step` per frame, lazily, so a caller may stop early (a time budget) or
    draw on the frame it gets back. Only the tracker calls are timed, not the reading or
    decoding of the frames.
    """
    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        return
    t0 = time.perf_counter()
    result = tracker.init(first, init_box)
    yield Step(first, result, time.perf_counter() - t0)
    for frame in it:
        t0 = time.perf_counter()
        result = tracker.update(frame)
        yield Step(frame, result, time.perf_counter() - t0)


def run_sequence(tracker: Tracker, frames: Iterable[np.ndarray], init_box: Box) -> SequenceRun:
    """One-pass evaluation of a whole sequence (OPE: init on the first frame, never re-init)."""
    run = SequenceRun()
    for step in track_frames(tracker, frames, init_box):
        run.results.append(step.result)
        run.times.append(step.seconds)
    return run
