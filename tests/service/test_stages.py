"""The workers' CPU accounting by stage (``service/stages.py``): what is added from any
thread is summed per stage and handed to the counter once per flush, nothing lost, nothing
counted twice."""

from __future__ import annotations

import threading
import time
from collections import defaultdict

import pytest

from arcf.service.stages import STAGES, StageClock


class _Counter:
    """A Prometheus counter's ``labels(stage=...).inc(v)``, recorded."""

    def __init__(self) -> None:
        self.total: dict[str, float] = defaultdict(float)
        self.calls = 0

    def labels(self, stage: str) -> _Counter:
        self._stage = stage
        return self

    def inc(self, value: float) -> None:
        self.total[self._stage] += value
        self.calls += 1


def test_additions_from_many_threads_are_summed_and_flushed_once() -> None:
    counter = _Counter()
    clock = StageClock(counter)

    def work() -> None:
        for _ in range(1000):
            clock.add("receive", 0.001)
            clock.add("track", 0.002)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert counter.calls == 0  # nothing reaches the counter before a flush
    clock.flush()
    assert counter.total["receive"] == pytest.approx(4.0)
    assert counter.total["track"] == pytest.approx(8.0)
    assert counter.calls == 2  # one increment per stage that moved
    clock.flush()  # nothing new: nothing added
    assert counter.calls == 2
    assert set(counter.total) <= set(STAGES)


def test_since_charges_this_threads_cpu_and_chains_the_next_stage() -> None:
    counter = _Counter()
    clock = StageClock(counter)
    c0 = time.thread_time()
    deadline = c0 + 0.02
    while time.thread_time() < deadline:  # 20 ms of this thread's CPU
        pass
    c1 = clock.since("decode", c0)
    assert c1 >= deadline
    clock.since("publish", c1)
    clock.flush()
    assert counter.total["decode"] >= 0.02
    assert counter.total["publish"] < counter.total["decode"]
    with pytest.raises(KeyError):
        clock.add("lunch", 1.0)  # only the declared stages
