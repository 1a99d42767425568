"""Overload and soak runs against a live ``arcf-service``: what a fixed-level load test can't show.

- **Overload** (:func:`run_overload`): the service's capacity is measured in the same run (streams
  added one at a time until p99 latency or a drop fails the criterion), then three times as many
  streams are offered, then the load falls back to capacity. Above capacity a worker keeps only
  the newest ``frame_queue`` frames of each stream, so the latency of the frames it does process
  must stay bounded while the oldest are dropped and counted (in every result's ``dropped`` and
  in ``arcf_frames_dropped_total``); memory must stay bounded; and once the load falls the
  remaining streams must be served as before.
- **Soak** (:func:`run_soak`): a steady load of streams that come and go (each with a random
  lifetime, re-initialised whenever its clip starts over, some with two sessions, some reusing
  an old stream id)
  for a long time, with the service's memory sampled throughout: it must not grow beyond a
  small bound once warm.

Both drive a :class:`Fleet` of streams that can be added and removed while the service runs.
A stream replays the first ``window`` frames of a real sequence forth and back (a palindrome,
so the target moves continuously and a session never has to be re-initialised at a wrap).
Memory is read from ``/proc/<pid>/smaps_rollup`` for the service's whole process tree: the
anonymous memory (where a leak would show; see :func:`memory_mb`), with PSS and RSS beside it.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import random
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .loadtest import _percentiles, _process_tree, meets_capacity
from .scrape import scrape

GOLDEN = 0.6180339887498949


# --------------------------------------------------------------------------- memory
def memory_mb(pid: int) -> dict[str, float]:
    """Memory of ``pid`` and its descendants (MB): anonymous, PSS and RSS, and how many
    processes that is.

    Anonymous memory (heap, NumPy arrays, Zenoh's buffers) is where a leak shows, and it is
    the service's alone. PSS and RSS also count pages of shared libraries, and PSS splits those
    between every process on the machine that maps them, so it moves when unrelated processes
    start or stop: reported, but not what the bounds are checked on."""
    out = {"anon_mb": 0.0, "pss_mb": 0.0, "rss_mb": 0.0}
    fields = {"Anonymous:": "anon_mb", "Pss:": "pss_mb", "Rss:": "rss_mb"}
    pids = _process_tree(pid)
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


# --------------------------------------------------------------------------- the fleet
@dataclass
class _SimulatedStream:
    """One simulated drone of the fleet: its frames, sessions and what came back."""

    name: str
    index: int
    frames: list[bytes]
    box: tuple[float, ...]
    sessions: list[str] = field(default_factory=list)
    #: (frame seq, monotonic time sent)
    sent: list[tuple[int, float]] = field(default_factory=list)
    #: (session, frame seq, monotonic time received, latency s, dropped, status, track s, scale)
    results: list[tuple[str, int, float, float, int, str, float, float]] = field(
        default_factory=list)
    stop: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None
    sub: Any = None
    reinit_on_wrap: bool = False


class Fleet:
    """Streams of real frames that can be added and removed while the service runs.

    Each stream has its own thread, paced at ``fps`` with its phase spread over the frame
    period (independent cameras are not synchronised), and ``sessions`` tracking sessions
    started on the sequence's first box at frame 0. Latency is capture (publication) to
    result received, as in ``arcf-loadtest``.
    """

    def __init__(self, client: Any, sequences: list[Any], *, preset: str = "arcf-h",
                 fps: float = 10.0, window: int = 40) -> None:
        self.client, self.preset, self.fps = client, preset, fps
        self._clips = []
        for seq in sequences:
            data = [p.read_bytes() for p in seq.frames[:window]]
            # forth and back: 0 1 ... n-1 n-2 ... 1, repeated
            self._clips.append((seq.name, tuple(seq.init_box), data + data[-2:0:-1]))
        self.live: list[_SimulatedStream] = []
        self.ended: list[_SimulatedStream] = []
        self._count = 0
        self.sessions_started = 0
        self.sessions_stopped = 0

    def add(self, n: int = 1, *, sessions: int = 1, name: str | None = None,
            reinit_on_wrap: bool = False) -> list[_SimulatedStream]:
        """Start ``n`` streams (``name`` only with n=1, e.g. to reuse a stream id). With
        ``reinit_on_wrap`` the sessions are re-initialised on the first box each time the
        clip starts over (the one frame where that box is right)."""
        out = []
        for _ in range(n):
            k = self._count
            self._count += 1
            clip_name, box, frames = self._clips[k % len(self._clips)]
            st = _SimulatedStream(name or f"stress-{k}-{clip_name}", k, frames, box,
                         reinit_on_wrap=reinit_on_wrap)

            def on_result(r: Any, st: _SimulatedStream = st) -> None:
                now = time.monotonic()
                st.results.append((r.session_id, r.frame_seq, now,
                                   (time.time_ns() - r.capture_ts_ns) / 1e9, r.dropped,
                                   r.status.value, r.track_s, r.scale))

            st.sub = self.client.results(st.name, callback=on_result)
            for _ in range(sessions):
                st.sessions.append(self.client.start(st.name, box, preset=self.preset,
                                                     frame_seq=0).session_id)
                self.sessions_started += 1
            st.thread = threading.Thread(target=self._publish, args=(st,), daemon=True,
                                         name=f"publish-{st.name}")
            st.thread.start()
            self.live.append(st)
            out.append(st)
        return out

    def _publish(self, st: _SimulatedStream) -> None:
        period = 1.0 / self.fps
        t0 = time.monotonic() + ((st.index * GOLDEN) % 1.0) * period
        i = 0
        while not st.stop.is_set():
            delay = t0 + i * period - time.monotonic()
            if delay > 0 and st.stop.wait(delay):
                break
            if st.reinit_on_wrap and i and i % len(st.frames) == 0:
                for sid in st.sessions:  # a new box on this frame: the tracker starts over
                    self.client.reinit(sid, st.box, frame_seq=i)
            self.client.publish_frame(st.name, data=st.frames[i % len(st.frames)], seq=i)
            st.sent.append((i, time.monotonic()))
            i += 1

    def remove(self, n: int = 1, *, streams: list[_SimulatedStream] | None = None) -> None:
        """Stop ``streams`` (default: the ``n`` newest): publishing stops, then the sessions."""
        chosen = streams if streams is not None else self.live[-n:] if n else []
        for st in chosen:
            st.stop.set()
        for st in chosen:
            assert st.thread is not None
            st.thread.join(timeout=5)
            for sid in st.sessions:
                self.client.stop(sid)
                self.sessions_stopped += 1
            time.sleep(0.05)
            st.sub.close()
            self.live.remove(st)
            self.ended.append(st)

    def close(self) -> None:
        self.remove(streams=list(self.live))

    # ------------------------------------------------------------------ measurements
    def streams(self) -> list[_SimulatedStream]:
        return self.ended + self.live

    def window(self, t0: float, t1: float, streams: list[_SimulatedStream] | None = None
               ) -> dict[str, Any]:
        """What happened between monotonic times t0 and t1: frames offered, results, frames
        the service reported dropped (``dropped`` of the results received), latency."""
        chosen = streams if streams is not None else self.streams()
        sent = sum(1 for st in chosen for _, t in st.sent if t0 <= t <= t1)
        got = [r for st in chosen for r in st.results if t0 <= r[2] <= t1]
        sessions = max(np.mean([len(st.sessions) for st in chosen]), 1) if chosen else 1
        dropped = sum(r[4] for r in got)
        span = max(t1 - t0, 1e-9)
        return {"seconds": span, "offered_fps": sent / span,
                "processed_fps": len(got) / sessions / span,
                "results": len(got), "dropped": dropped,
                "drop_fraction": dropped / max(dropped + len(got), 1),
                "errors": sum(1 for r in got if r[5] == "error"),
                "latency_ms": _percentiles([r[3] for r in got]),
                "track_ms": float(np.nanmean([r[6] for r in got]) * 1e3) if got else float("nan"),
                "scale": float(np.nanmedian([r[7] for r in got])) if got else float("nan")}

    def ledger(self) -> dict[str, int]:
        """Every frame of every session accounted for, over the whole run.

        Per session, its results' frame numbers must increase, and each frame up to the last
        one answered either has a result or is counted in a later result's ``dropped`` (frames
        before the session's first result are counted here as skipped at the start). Frames
        sent after the last answered one were still queued when the stream stopped."""
        out = {"sessions": 0, "results": 0, "dropped": 0, "skipped_at_start": 0,
               "unaccounted": 0, "out_of_order": 0, "tail": 0}
        for st in self.streams():
            n_sent = len(st.sent)
            for sid in st.sessions:
                rows = [r for r in st.results if r[0] == sid and r[5] != "stopped"]
                out["sessions"] += 1
                if not rows:
                    out["tail"] += n_sent
                    continue
                seqs = [r[1] for r in rows]
                out["out_of_order"] += sum(1 for a, b in itertools.pairwise(seqs) if b <= a)
                dropped = sum(r[4] for r in rows[1:])
                out["results"] += len(rows)
                out["dropped"] += dropped
                out["skipped_at_start"] += seqs[0]
                out["unaccounted"] += abs(seqs[-1] + 1 - seqs[0] - dropped - len(rows))
                out["tail"] += n_sent - (seqs[-1] + 1)
        return out


def _metrics_delta(before: dict[str, float], metrics_url: str | None) -> dict[str, float]:
    """How much each of the service's counters moved since ``before`` (histogram buckets
    left out: their counts and sums are kept)."""
    after = scrape(metrics_url)
    return {k: after.get(k, 0.0) - before.get(k, 0.0) for k in after
            if not k.endswith(("_bucket", "_created"))}


# --------------------------------------------------------------------------- overload
def passes(stats: dict[str, Any], p99_ms: float) -> bool:
    """``meets_capacity`` of a fleet window's statistics."""
    return meets_capacity(stats["results"], stats["dropped"], stats["latency_ms"]["p99"], p99_ms)


def find_capacity(fleet: Fleet, *, p99_ms: float = 100.0, step_s: float = 10.0,
                  settle_s: float = 2.0, max_streams: int = 16, warmup_s: float = 3.0,
                  log: Any = None) -> int:
    """Add streams one at a time while the criterion holds; leave the fleet at the largest
    count that passed (it removes the stream that failed) and return that count.

    The first stream runs ``warmup_s`` unmeasured (a fresh worker's first frames pay for
    imports, FFT plans and allocator growth), and a level fails only if it fails twice in a row:
    on a shared machine one noisy step would otherwise decide the capacity."""
    fleet.add(1)
    time.sleep(warmup_s)
    while True:
        for attempt in (1, 2):
            t0 = time.monotonic()
            time.sleep(step_s)
            stats = fleet.window(t0 + settle_s, time.monotonic(), fleet.live)
            ok = passes(stats, p99_ms)
            if log:
                log(f"capacity: {len(fleet.live)} streams, p99 "
                    f"{stats['latency_ms']['p99']:.0f} ms, dropped {stats['dropped']}: "
                    f"{'pass' if ok else 'fail' if attempt == 2 else 'fail, measuring again'}")
            if ok:
                break
        if not ok:
            fleet.remove(1)
            return len(fleet.live)
        if len(fleet.live) >= max_streams:
            return len(fleet.live)
        fleet.add(1)


def saturation_capacity(fleet: Fleet, *, streams: int = 12, seconds: float = 8.0,
                        settle_s: float = 3.0, headroom: float = 0.8,
                        max_streams: int = 96) -> int:
    """Capacity from throughput rather than latency: offer ``streams`` streams (far more than
    the workers can track), count the frames processed per second, and return how many
    streams at the fleet's rate fit in ``headroom`` of that. An average over seconds of
    saturation is far steadier on a shared machine than a p99 over a few seconds.

    If the workers keep up with the offer (it was no saturation: 90 % or more processed), the
    offer doubles and the measurement is repeated, up to ``max_streams`` streams; a faster
    tracker would otherwise be sized by what was offered, not by what it can do. If they
    still keep up at ``max_streams``, the result is a lower bound (logged by the caller's
    ``run_overload`` as the capacity it used)."""
    if streams < 1 or max_streams < streams:
        raise ValueError(f"need 1 <= streams <= max_streams, got {streams}, {max_streams}")
    while True:
        added = fleet.add(streams)
        t0 = time.monotonic()
        time.sleep(settle_s + seconds)
        w = fleet.window(t0 + settle_s, time.monotonic(), added)
        fleet.remove(streams=added)
        if w["processed_fps"] < 0.9 * w["offered_fps"] or streams >= max_streams:
            return int(headroom * w["processed_fps"] / fleet.fps)
        streams = min(2 * streams, max_streams)


def timeline(fleet: Fleet, memory: MemorySampler, t0: float, t1: float,
             bin_s: float = 1.0) -> list[dict[str, float]]:
    """Per-second figures from t0 to t1 (time relative to t0): for plots and for seeing how
    fast latency and drops follow the load up and down."""
    rows = []
    for a in np.arange(t0, t1 - bin_s + 1e-9, bin_s):
        w = fleet.window(a, a + bin_s)
        mem = memory.between(a, a + bin_s)
        live = sum(1 for st in fleet.streams() if st.sent and st.sent[0][1] <= a + bin_s
                   and st.sent[-1][1] >= a)
        rows.append({"t": float(a - t0), "streams": live, "offered_fps": w["offered_fps"],
                     "results": w["results"], "dropped": w["dropped"],
                     "p50_ms": w["latency_ms"]["p50"], "p99_ms": w["latency_ms"]["p99"],
                     "track_ms": w["track_ms"],
                     "anon_mb": float(mem[:, 1].mean()) if len(mem) else float("nan"),
                     "pss_mb": float(mem[:, 2].mean()) if len(mem) else float("nan")})
    return rows


def recovery_time(bins: list[dict[str, float]], bar_ms: float, max_drop: float,
                  sustain: int = 5) -> float:
    """Seconds from the fall of the load (``bins[0]``) until the first of ``sustain``
    consecutive 1-s bins that each drop at most ``max_drop`` of their frames and keep p99
    under ``bar_ms`` (NaN if that never happens). Consecutive bins, not "every later bin": on
    a shared machine a neighbour's burst can slow any second of a long phase."""
    def good(b: dict[str, float]) -> bool:
        total = b["results"] + b["dropped"]
        return bool(b["results"]) and b["dropped"] <= max_drop * total and b["p99_ms"] < bar_ms

    ok = [good(b) for b in bins]
    for k in range(len(ok) - sustain + 1):
        if all(ok[k:k + sustain]):
            return float(k + 1)
    return float("nan")


def run_overload(client: Any, sequences: list[Any], *, service_pid: int,
                 metrics_url: str | None = None, preset: str = "arcf-h", fps: float = 10.0,
                 capacity: int | None = None, factor: float = 3.0, phase_s: float = 30.0,
                 settle_s: float = 3.0, p99_ms: float = 100.0, window: int = 40,
                 max_streams: int = 16, step_s: float = 10.0, nominal_share: float = 1.0,
                 capacity_from: str = "latency", log: Any = None) -> dict[str, Any]:
    """Capacity, then ``factor`` times capacity, then capacity again; one report.

    ``nominal_share`` of the capacity (at least one stream) runs before and after the
    overload. Below the capacity, the before/after comparison does not sit on the edge where a
    shared machine's noise alone makes frames drop. ``capacity_from="throughput"`` sizes the
    capacity with :func:`saturation_capacity` instead of the latency ramp."""
    fleet = Fleet(client, sequences, preset=preset, fps=fps, window=window)
    memory = MemorySampler(service_pid, interval=1.0).start()
    before = scrape(metrics_url)
    try:
        t_ramp = time.monotonic()
        if capacity is None and capacity_from == "throughput":
            capacity = saturation_capacity(fleet)
            if log:
                log(f"capacity from throughput: {capacity} streams")
            fleet.add(capacity)
        elif capacity is None:
            capacity = find_capacity(fleet, p99_ms=p99_ms, step_s=step_s,
                                     max_streams=max_streams, log=log)
        else:
            fleet.add(capacity)
        if capacity == 0:
            raise RuntimeError(f"not even one {fps:g} fps stream meets p99 < {p99_ms} ms")
        nominal = min(capacity, max(1, int(capacity * nominal_share)))
        fleet.remove(capacity - nominal)
        base = list(fleet.live)
        marks = {"ramp": t_ramp, "nominal": time.monotonic()}
        time.sleep(phase_s)
        marks["overload"] = time.monotonic()
        extra = round(capacity * factor) - nominal
        if log:
            log(f"overload: {nominal} -> {nominal + extra} streams")
        fleet.add(extra)
        time.sleep(phase_s)
        marks["recovery"] = time.monotonic()
        if log:
            log(f"recovery: back to {nominal} streams")
        fleet.remove(extra)
        marks["recovery_started"] = time.monotonic()  # the extra streams are stopped
        time.sleep(phase_s)
        marks["end"] = time.monotonic()
        fleet.close()
        time.sleep(0.5)
    finally:
        memory.stop()
        if fleet.live:
            fleet.close()
    delta = _metrics_delta(before, metrics_url)

    def phase(name: str, start: str, end: str, streams: list[_SimulatedStream] | None = None
              ) -> dict[str, Any]:
        a, b = marks[start] + settle_s, marks[end]
        stats = fleet.window(a, b, streams)
        half = (a + b) / 2
        first, second = fleet.window(a, half, streams), fleet.window(half, b, streams)
        stats["latency_ms_first_half"] = first["latency_ms"]
        stats["latency_ms_second_half"] = second["latency_ms"]
        stats["memory"] = memory.summary(a, b)
        stats["streams"] = len(streams) if streams is not None else len(
            [st for st in fleet.streams() if st.sent and st.sent[0][1] <= b
             and st.sent[-1][1] >= a])
        return {"phase": name, **stats}

    ledger = fleet.ledger()
    phases = [phase("nominal", "nominal", "overload", base),
              phase("overload", "overload", "recovery"),
              phase("recovery", "recovery_started", "end", base)]
    # recovered: as good as before the overload. On a shared machine the nominal phase itself
    # may exceed the capacity criterion now and then, so the bar is the worse of the two.
    bar = max(p99_ms, 1.25 * phases[0]["latency_ms"]["p99"])
    max_drop = max(0.01, 2 * phases[0]["drop_fraction"])
    after_fall = timeline(fleet, memory, marks["recovery_started"], marks["end"])
    return {
        "preset": preset, "fps": fps, "capacity": capacity, "factor": factor,
        "marks_s": {k: v - marks["nominal"] for k, v in marks.items()},
        "timeline": timeline(fleet, memory, marks["nominal"], marks["end"]),
        "nominal_streams": nominal, "overload_streams": round(capacity * factor),
        "phase_s": phase_s,
        "p99_criterion_ms": p99_ms, "window": window,
        "sequences": sorted({c[0] for c in fleet._clips}),
        "phases": phases,
        "recovery_bar_ms": bar,
        "recovery_max_drop": max_drop,
        "recovery_s": recovery_time(after_fall, bar, max_drop),
        "memory_ramp_start_mb": memory.summary(marks["ramp"], marks["ramp"] + 2.0),
        "ledger": ledger,
        "results_dropped_total": ledger["dropped"],
        "metrics_delta": delta,
    }


# --------------------------------------------------------------------------- soak
def run_soak(client: Any, sequences: list[Any], *, service_pid: int,
             metrics_url: str | None = None, preset: str = "arcf-h", fps: float = 10.0,
             streams: int = 4, duration_s: float = 1200.0, warmup_s: float = 120.0,
             lifetime_s: tuple[float, float] = (20.0, 60.0), window: int = 40,
             sample_s: float = 5.0, seed: int = 0, log: Any = None) -> dict[str, Any]:
    """``streams`` streams at a time for ``duration_s``, each living a random time, replaced by
    a new one when it ends. Every third stream has two sessions, every fifth reuses the id of a
    stream that ended, and sessions are re-initialised each time their clip starts over."""
    rng = random.Random(seed)
    fleet = Fleet(client, sequences, preset=preset, fps=fps, window=window)
    memory = MemorySampler(service_pid, interval=sample_s).start()
    before = scrape(metrics_url)
    deadline: dict[str, float] = {}
    t_start = time.monotonic()
    t_end = t_start + duration_s
    started = 0

    def spawn() -> None:
        nonlocal started
        life = rng.uniform(*lifetime_s)
        reuse = started % 5 == 4 and fleet.ended
        name = fleet.ended[rng.randrange(len(fleet.ended))].name if reuse else None
        if name is not None and any(st.name == name for st in fleet.live):
            name = None
        (st,) = fleet.add(1, sessions=2 if started % 3 == 2 else 1, name=name,
                          reinit_on_wrap=True)
        deadline[st.name] = time.monotonic() + life
        started += 1

    try:
        for _ in range(streams):
            spawn()
        next_report = t_start + 60
        while time.monotonic() < t_end:
            time.sleep(0.2)
            now = time.monotonic()
            for st in [s for s in fleet.live if deadline[s.name] <= now]:
                fleet.remove(streams=[st])
                spawn()
            if log and now >= next_report:
                next_report += 60
                m = memory.samples[-1] if memory.samples else (0, float("nan"), 0, 0, 0)
                log(f"soak {now - t_start:.0f} s: {started} streams so far, "
                    f"anonymous memory {m[1]:.1f} MB")
        fleet.close()
        time.sleep(1.0)
    finally:
        memory.stop()
        if fleet.live:
            fleet.close()
    delta = _metrics_delta(before, metrics_url)
    # warm: the first window after warm-up; end: the same length at the end of the run
    span = min(max(60.0, 10 * sample_s), (duration_s - warmup_s) / 3)
    warm = memory.summary(t_start + warmup_s, t_start + warmup_s + span)
    end = memory.summary(t_end - span, t_end)
    steady = memory.summary(t_start + warmup_s, t_end)
    rows = memory.between(t_start, t_end + 2)
    return {
        "preset": preset, "fps": fps, "streams": streams, "duration_s": duration_s,
        "warmup_s": warmup_s, "lifetime_s": list(lifetime_s), "window": window,
        "streams_started": started, "sessions_started": fleet.sessions_started,
        "sessions_stopped": fleet.sessions_stopped,
        "frames_sent": sum(len(st.sent) for st in fleet.streams()),
        "load": fleet.window(t_start, t_end),
        "memory_start_mb": memory.summary(t_start, t_start + 2 * sample_s),
        "memory_warm_mb": warm, "memory_end_mb": end, "memory_steady": steady,
        "growth_mb": end.get("anon_median_mb", float("nan")) - warm.get("anon_median_mb",
                                                                            float("nan")),
        #: [seconds since start, anonymous MB, PSS MB, RSS MB]
        "memory_series": [[round(r[0] - t_start, 1), round(r[1], 1), round(r[2], 1),
                           round(r[3], 1)] for r in rows],
        "ledger": fleet.ledger(),
        "metrics_delta": delta,
    }


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown"


def machine() -> dict[str, Any]:
    return {"nproc": os.cpu_count(), "cpu": cpu_model()}
