"""Overload and soak against a real service (two workers, embedded Zenoh router, real JPEG
frames from UAV123@10fps): the short versions of benchmarks/overload.py and benchmarks/soak.py.

Overload: capacity is measured first, in the same run, then three times as many streams are
offered, then the load falls back. Soak: streams with short lifetimes come and go for a minute
while the service's memory is sampled.
"""

from __future__ import annotations

import pytest
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.stress import run_overload, run_soak
from arcf.service.client import TrackingClient
from arcf.service.settings import ServiceSettings

from arcf.data import data_root
from arcf.eval import load_dataset

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

FPS = 10.0
# the capacity is sized from saturation throughput (80 % of it), not from the benchmark's p99
# ramp: on a busy shared machine that ramp can underestimate it threefold, and then three times
# "capacity" is no overload at all. P99_MS is the latency bar for "served as before".
P99_MS = 150.0


@pytest.fixture(scope="module")
def wakeboard() -> list:
    return load_dataset("uav123_10fps", sequences=["wakeboard7"])


def test_three_times_capacity(wakeboard: list) -> None:
    svc = ServiceProcess(workers=2)
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            r = run_overload(client, wakeboard, service_pid=svc.pid,
                             metrics_url=svc.metrics_url, preset="arcf-h", fps=FPS,
                             factor=3.0, phase_s=10.0, settle_s=2.0, step_s=5.0,
                             max_streams=10, window=30, p99_ms=P99_MS, nominal_share=0.5,
                             capacity_from="throughput")
            # the service still takes new work afterwards
            assert client.status().streams == []
    finally:
        assert svc.stop() == 0
    nominal, overload, recovery = r["phases"]
    capacity = r["capacity"]
    for p in r["phases"]:  # shown if an assertion fails
        print(p["phase"], p["streams"], "streams, dropped", p["dropped"], "latency",
              {k: round(v) for k, v in p["latency_ms"].items()}, "memory", p["memory"])
    print("per second:", [(round(x["t"]), x["streams"], x["dropped"], round(x["p99_ms"]))
                          for x in r["timeline"]])
    assert capacity >= 1 and overload["streams"] == 3 * capacity
    assert nominal["errors"] == overload["errors"] == recovery["errors"] == 0
    assert r["metrics_delta"].get("arcf_errors_total", 0) == 0

    # above capacity the service keeps its throughput and drops the rest...
    assert overload["offered_fps"] == pytest.approx(3 * capacity * FPS, rel=0.1)
    assert overload["processed_fps"] >= 0.7 * capacity * FPS  # what it sustained at capacity
    assert overload["drop_fraction"] > 0.2
    # ...oldest first: only the newest frame_queue frames per stream wait, so the latency of a
    # processed frame stays within frame_queue frame periods plus a frame's work, and it does
    # not grow while the overload lasts
    # (every second of the overload but one: a shared CI machine once stalled the service for
    # one second, 725 ms p99 between seconds of 210 ms; unbounded queueing fails them all)
    bound_ms = 1e3 * ServiceSettings().frame_queue / FPS + 350
    assert overload["latency_ms"]["p95"] < bound_ms
    over_s = [x for x in r["timeline"] if x["streams"] == overload["streams"]]
    assert len(over_s) >= 5
    assert sum(x["p99_ms"] >= bound_ms for x in over_s) <= 1, over_s
    first, second = overload["latency_ms_first_half"], overload["latency_ms_second_half"]
    assert second["p50"] < 1.5 * first["p50"] + 50

    # every frame is answered or counted: in the results' ``dropped`` and in the metric
    ledger = r["ledger"]
    assert ledger["unaccounted"] == 0 and ledger["out_of_order"] == 0
    assert ledger["dropped"] > 0
    assert r["metrics_delta"]["arcf_frames_dropped_total"] == ledger["dropped"]
    assert ledger["tail"] <= 4 * ledger["sessions"]

    # memory: bounded while overloaded, and back near where it was
    mem_nominal, mem_over = nominal["memory"], overload["memory"]
    assert mem_over["anon_max_mb"] < mem_nominal["anon_median_mb"] + 150
    assert abs(mem_over["anon_trend_mb_per_min"]) < 60  # i.e. under 10 MB over the phase
    assert recovery["memory"]["anon_median_mb"] < mem_nominal["anon_median_mb"] + 50

    # once the load falls, the remaining streams are served as before. Before and after run
    # half the capacity: at the capacity itself a shared machine's noise alone drops frames
    assert r["recovery_s"] <= 5.0
    tail = recovery["latency_ms_second_half"]
    assert tail["p99"] < max(1.5 * nominal["latency_ms"]["p99"], P99_MS)
    assert recovery["drop_fraction"] <= max(0.02, 2 * nominal["drop_fraction"])


def test_soak_sessions_come_and_go(wakeboard: list) -> None:
    svc = ServiceProcess(workers=2)
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            r = run_soak(client, wakeboard, service_pid=svc.pid,
                         metrics_url=svc.metrics_url, preset="arcf-h", fps=FPS, streams=3,
                         duration_s=60.0, warmup_s=20.0, lifetime_s=(2.0, 5.0), window=20,
                         sample_s=1.0)
        assert svc.metric("arcf_active_sessions") == 0
        assert svc.metric("arcf_active_streams") == 0
    finally:
        assert svc.stop() == 0
    # dozens of sessions started and stopped, some two to a stream, some on reused ids
    assert r["streams_started"] >= 25
    assert r["sessions_started"] == r["sessions_stopped"] > r["streams_started"]
    assert r["ledger"]["unaccounted"] == 0 and r["ledger"]["out_of_order"] == 0
    assert r["metrics_delta"].get("arcf_errors_total", 0) == 0, r["errors_by_kind"]
    # after warm-up the service's memory (anonymous, all its processes) stays flat
    assert r["growth_mb"] < 5.0  # leaking one tracker per session shows as about 8 MB
    assert r["memory_steady"]["anon_max_mb"] - r["memory_warm_mb"]["anon_median_mb"] < 20.0
    assert r["memory_steady"]["processes"] == r["memory_warm_mb"]["processes"]
