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

Both drive a :class:`~arcf.loadtools.driver.Fleet` of fixed-rate streams that are added and removed
while the service runs. A stream replays the first ``window`` frames of a real sequence forth
and back (a palindrome clip). Memory is sampled for the service's whole process tree
(:class:`~arcf.loadtools.system.MemorySampler`: the anonymous memory, where a leak would show, with
PSS and RSS beside it).
"""

from __future__ import annotations

import random
import time
from typing import Any

import numpy as np

from arcf.service.scrape import by_label, fetch, scrape
from arcf.service.scrape import delta as metrics_delta

from .driver import Clip, Fleet, Pacing, SimulatedStream
from .ledger import meets_capacity
from .system import MemorySampler


def _stress_fleet(client: Any, sequences: list[Any], preset: str, fps: float,
                  window: int) -> Fleet:
    """Streams at ``fps``, each replaying the first ``window`` frames of a sequence forth and
    back."""
    clips = [Clip.of(seq, limit=window, palindrome=True) for seq in sequences]
    return Fleet(client, clips, preset=preset, pacing=Pacing.fixed_rate(fps), prefix="stress")


# --------------------------------------------------------------------------- overload
def passes(stats: dict[str, Any], p99_ms: float) -> bool:
    """``meets_capacity`` of a fleet window's statistics. Inside a window of a running fleet a
    frame still in flight cannot be told from a lost one, so what is lost here is what the
    service itself reported dropped (``run_load`` adds the frames never answered, which it
    can count once every stream has stopped)."""
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
        live = len(fleet.ledger.live_between(a, a + bin_s))
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
    fleet = _stress_fleet(client, sequences, preset, fps, window)
    before = scrape(metrics_url)
    errors_before = _errors_by_kind(metrics_url)
    with MemorySampler(service_pid, interval=1.0) as memory, fleet:
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
        # measured from here: starting the extra sessions takes a while on a loaded machine
        # (each a round trip through the control plane and its worker), and the phase is
        # about the overload, not about its ramp
        marks["overload_started"] = time.monotonic()
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
    delta = metrics_delta(before, scrape(metrics_url))
    errors = _errors_delta(errors_before, metrics_url)

    def phase(name: str, start: str, end: str, streams: list[SimulatedStream] | None = None
              ) -> dict[str, Any]:
        a, b = marks[start] + settle_s, marks[end]
        stats = fleet.window(a, b, streams)
        half = (a + b) / 2
        first, second = fleet.window(a, half, streams), fleet.window(half, b, streams)
        stats["latency_ms_first_half"] = first["latency_ms"]
        stats["latency_ms_second_half"] = second["latency_ms"]
        stats["memory"] = memory.summary(a, b)
        stats["streams"] = (len(streams) if streams is not None
                            else len(fleet.ledger.live_between(a, b)))
        return {"phase": name, **stats}

    ledger = fleet.ledger.accounting()
    phases = [phase("nominal", "nominal", "overload", base),
              phase("overload", "overload_started", "recovery"),
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
        "sequences": sorted({c.name for c in fleet.clips}),
        "phases": phases,
        "recovery_bar_ms": bar,
        "recovery_max_drop": max_drop,
        "recovery_s": recovery_time(after_fall, bar, max_drop),
        "memory_ramp_start_mb": memory.summary(marks["ramp"], marks["ramp"] + 2.0),
        "ledger": ledger,
        "results_dropped_total": ledger["dropped"],
        "metrics_delta": delta,
        "errors_by_kind": errors,
    }


# --------------------------------------------------------------------------- soak
def _errors_by_kind(metrics_url: str | None) -> dict[str, float]:
    return by_label(fetch(metrics_url), "arcf_errors_total", "kind") if metrics_url else {}


def _errors_delta(before: dict[str, float], metrics_url: str | None) -> dict[str, float]:
    """``arcf_errors_total`` by kind since ``before``, the kinds that grew."""
    now = _errors_by_kind(metrics_url)
    return {k: v - before.get(k, 0.0) for k, v in now.items() if v - before.get(k, 0.0)}


def run_soak(client: Any, sequences: list[Any], *, service_pid: int,
             metrics_url: str | None = None, preset: str = "arcf-h", fps: float = 10.0,
             streams: int = 4, duration_s: float = 1200.0, warmup_s: float = 120.0,
             lifetime_s: tuple[float, float] = (20.0, 60.0), window: int = 40,
             sample_s: float = 5.0, seed: int = 0, log: Any = None) -> dict[str, Any]:
    """``streams`` streams at a time for ``duration_s``, each living a random time, replaced by
    a new one when it ends. Every third stream has two sessions, every fifth reuses the id of a
    stream that ended, and sessions are re-initialised each time their clip starts over."""
    rng = random.Random(seed)
    fleet = _stress_fleet(client, sequences, preset, fps, window)
    memory = MemorySampler(service_pid, interval=sample_s)
    before = scrape(metrics_url)
    errors_before = _errors_by_kind(metrics_url)
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
        (st,) = fleet.add(1, sessions=2 if started % 3 == 2 else 1,
                          names=[name] if name else None,
                          reinit_on_wrap=True)
        deadline[st.name] = time.monotonic() + life
        started += 1

    with memory, fleet:
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
    delta = metrics_delta(before, scrape(metrics_url))
    errors = _errors_delta(errors_before, metrics_url)
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
        "frames_sent": sum(st.sent for st in fleet.streams()),
        "load": fleet.window(t_start, t_end),
        "memory_start_mb": memory.summary(t_start, t_start + 2 * sample_s),
        "memory_warm_mb": warm, "memory_end_mb": end, "memory_steady": steady,
        "growth_mb": end.get("anon_median_mb", float("nan")) - warm.get("anon_median_mb",
                                                                            float("nan")),
        #: [seconds since start, anonymous MB, PSS MB, RSS MB]
        "memory_series": [[round(r[0] - t_start, 1), round(r[1], 1), round(r[2], 1),
                           round(r[3], 1)] for r in rows],
        "ledger": fleet.ledger.accounting(),
        "metrics_delta": delta,
        "errors_by_kind": errors,
    }
