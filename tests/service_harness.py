"""The integration tests' service and router processes (see :mod:`service.procs`), and what the
failover tests measure on the results they collect: ``(Result, arrival time)`` per stream."""

from __future__ import annotations

import itertools
import time
from typing import Any

from service.procs import RouterProcess, ServiceProcess, free_port, worker_pids

__all__ = ["RouterProcess", "ServiceProcess", "first_resumed", "free_port", "gaps", "worker_pids"]


def gaps(results: list[tuple[Any, float]], t0: float, t1: float) -> int:
    """Frames with no result among those whose results arrived between t0 and t1."""
    seqs = sorted({r.frame_seq for r, t in results if t0 <= t <= t1})
    return sum(b - a - 1 for a, b in itertools.pairwise(seqs))


def first_resumed(results: dict[str, list], lock: Any, names: list[str], after: float,
                  timeout: float) -> dict[str, float]:
    """Arrival time of each stream's first "resumed" result after ``after`` (waits up to
    ``timeout`` s for all of ``names``; the ones never resumed are missing from the answer)."""
    deadline = time.monotonic() + timeout
    found: dict[str, float] = {}
    while time.monotonic() < deadline and len(found) < len(names):
        with lock:
            for n in names:
                hit = [t for r, t in results[n] if r.status.value == "resumed" and t > after]
                if hit:
                    found[n] = min(hit)
        time.sleep(0.05)
    return found
