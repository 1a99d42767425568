"""Where a worker's CPU goes, stage by stage of a frame's path.

A frame crosses: **receive** (Zenoh's callback: the payload copied out of the network buffer
and queued), **parse** (the ``frame`` message decoded and checked, its number admitted),
**decode** (JPEG / PNG to pixels, or a video unit through the stream's decoder), **convert** (a
decoded video picture to BGR, only when it is tracked), **track** (every session's
``init`` / ``update``), **publish** (each result built, encoded and put) and **metrics** (the
histograms and counters it feeds). The CPU time of each (``time.thread_time``: preemption by
other processes does not count) is summed here and added to ``arcf_stage_cpu_seconds_total``
once a second: a counter increment per frame and stage would itself be a visible cost. What
the worker's process spends outside these (Zenoh's own threads, the loop, housekeeping) is its
CPU time minus their sum (``benchmarks/service_profile.py``).
"""

from __future__ import annotations

import threading
import time
from typing import Any

#: the stages, in the order a frame crosses them
STAGES = ("receive", "parse", "decode", "convert", "track", "publish", "metrics")


class StageClock:
    """CPU seconds per stage since the last flush; ``add`` is safe from any thread (Zenoh's
    callbacks run on its own)."""

    def __init__(self, counter: Any) -> None:
        self._counter = counter
        self._spent = dict.fromkeys(STAGES, 0.0)
        self._lock = threading.Lock()

    def add(self, stage: str, seconds: float) -> None:
        with self._lock:
            self._spent[stage] += seconds

    def since(self, stage: str, start: float) -> float:
        """Add the calling thread's CPU time since ``start`` (a ``time.thread_time()``) to
        ``stage``; the current reading, to chain the next stage from."""
        now = time.thread_time()
        self.add(stage, now - start)
        return now

    def flush(self) -> None:
        with self._lock:
            spent, self._spent = self._spent, dict.fromkeys(STAGES, 0.0)
        for stage, seconds in spent.items():
            if seconds > 0:
                self._counter.labels(stage=stage).inc(seconds)
