"""CPU and memory of process trees, read from ``/proc``, and the machine a figure was taken on.

On a 2-core machine the load generator competes with the service's workers, so every figure of
the load tools says how much CPU each side used; leaks show in the anonymous memory of the
service's whole process tree (its main process and its workers).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..eval.environment import cpu_model as cpu_model  # re-exported: the load tools' name
from ..eval.environment import versions

_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def machine() -> dict[str, Any]:
    """What every benchmark records beside its figures: ``nproc``, the CPU model, and the
    versions of Python and the libraries (:func:`arcf.eval.environment.versions`), the last
    also as one printable string."""
    v = versions()
    return {"nproc": os.cpu_count(), "cpu": cpu_model(), "versions": v,
            "software": ", ".join(f"{k} {x}" for k, x in v.items())}


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of one process (0 if it is gone)."""
    with contextlib.suppress(OSError, IndexError, ValueError):
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / _TICK
    return 0.0


def process_tree(pid: int) -> set[int]:
    """``pid`` and all its descendants (the service's main process and its workers)."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, IndexError, ValueError):
            parents[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
    tree, grew = {pid}, True
    while grew:
        new = {c for c, p in parents.items() if p in tree} - tree
        tree |= new
        grew = bool(new)
    return tree


def _machine_ticks() -> tuple[int, int]:
    """(busy, total) CPU ticks of the whole machine since boot."""
    with contextlib.suppress(OSError, ValueError):
        values = [int(v) for v in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
        idle = values[3] + (values[4] if len(values) > 4 else 0)
        return sum(values) - idle, sum(values)
    return 0, 0


class CpuMeter:
    """CPU used during a run by this process (the load generator), the service (if its pid is
    known) and the whole machine, in cores (CPU seconds per wall second)."""

    def __init__(self, service_pid: int | None = None) -> None:
        self.service = sorted(process_tree(service_pid)) if service_pid else []
        self.t0 = time.monotonic()
        self.own0 = time.process_time()
        self.svc0 = {p: cpu_seconds(p) for p in self.service}
        self.machine0 = _machine_ticks()

    def read(self) -> dict[str, float]:
        wall = max(time.monotonic() - self.t0, 1e-9)
        busy1, total1 = _machine_ticks()
        busy0, total0 = self.machine0
        ncpu = os.cpu_count() or 1
        out = {"cpus": float(ncpu),
               "generator_cores": (time.process_time() - self.own0) / wall,
               "machine_cores": ncpu * (busy1 - busy0) / max(total1 - total0, 1)}
        if self.service:
            out["service_cores"] = sum(cpu_seconds(p) - c for p, c in self.svc0.items()) / wall
        return out


def memory_mb(pid: int) -> dict[str, float]:
    """Memory of ``pid`` and its descendants (MB): anonymous, PSS and RSS, and how many
    processes that is.

    Anonymous memory (heap, NumPy arrays, Zenoh's buffers) is where a leak shows, and it is
    the service's alone. PSS and RSS also count pages of shared libraries, and PSS splits those
    between every process on the machine that maps them, so it moves when unrelated processes
    start or stop: reported, but not what the bounds are checked on."""
    out = {"anon_mb": 0.0, "pss_mb": 0.0, "rss_mb": 0.0}
    fields = {"Anonymous:": "anon_mb", "Pss:": "pss_mb", "Rss:": "rss_mb"}
    pids = process_tree(pid)
    for p in pids:
        with contextlib.suppress(OSError, ValueError):
            for line in Path(f"/proc/{p}/smaps_rollup").read_text().splitlines():
                key = fields.get(line.split(" ", 1)[0])
                if key:
                    out[key] += int(line.split()[1]) / 1024
    return {**out, "processes": float(len(pids))}


class MemorySampler:
    """Samples :func:`memory_mb` of a process tree every ``interval`` seconds, on a thread."""

    COLUMNS = ("t", "anon_mb", "pss_mb", "rss_mb", "processes")

    def __init__(self, pid: int, interval: float = 1.0) -> None:
        self.pid, self.interval = pid, interval
        #: rows of COLUMNS (t: monotonic seconds)
        self.samples: list[tuple[float, float, float, float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="memory-sampler", daemon=True)

    def start(self) -> MemorySampler:
        self._thread.start()
        return self

    def _run(self) -> None:
        while True:
            m = memory_mb(self.pid)
            self.samples.append((time.monotonic(), m["anon_mb"], m["pss_mb"], m["rss_mb"],
                                 m["processes"]))
            if self._stop.wait(self.interval):
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5 + self.interval)

    def __enter__(self) -> MemorySampler:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def between(self, t0: float, t1: float) -> np.ndarray:
        """Samples in [t0, t1], one row per sample, columns as in COLUMNS."""
        rows = [s for s in self.samples if t0 <= s[0] <= t1]
        return np.asarray(rows, dtype=float).reshape(-1, len(self.COLUMNS))

    def summary(self, t0: float, t1: float) -> dict[str, float]:
        """Median, min and max anonymous memory in a window and its linear trend (MB per
        minute); PSS median and RSS max for reference."""
        rows = self.between(t0, t1)
        if len(rows) == 0:
            return {"samples": 0}
        anon = rows[:, 1]
        slope = float(np.polyfit(rows[:, 0], anon, 1)[0]) * 60 if len(rows) >= 3 else float("nan")
        return {"samples": len(rows), "anon_median_mb": float(np.median(anon)),
                "anon_min_mb": float(anon.min()), "anon_max_mb": float(anon.max()),
                "anon_trend_mb_per_min": slope, "pss_median_mb": float(np.median(rows[:, 2])),
                "rss_max_mb": float(rows[:, 3].max()), "processes": int(rows[:, 4].max())}
