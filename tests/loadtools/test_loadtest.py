"""A short load against a real service: the report's invariants hold."""

from __future__ import annotations

import pytest

pytest.importorskip("zenoh")

from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.loadtest import markdown, run_load
from arcf.loadtools.procs import ServiceProcess

pytestmark = [pytest.mark.integration, pytest.mark.heavy,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]


def test_short_load_accounts_for_every_frame() -> None:
    seqs = load_dataset("uav123_10fps", sequences=["wakeboard7", "truck4_1"])
    svc = ServiceProcess()
    try:
        report = run_load([svc.endpoint], seqs, streams=3, preset="bacf", fps=10.0,
                          duration=4.0, max_frames=30, stagger=0.1, reference_seconds=2.0,
                          metrics_url=svc.metrics_url, progress=False)
    finally:
        assert svc.stop() == 0
    assert report["streams"] == 3 and len(report["per_stream"]) == 3
    assert report["frames_sent"] > 0
    # every frame has a result or is counted as dropped; none vanishes
    assert report["missing"] == 0
    assert report["results"] + report["dropped_by_service"] == report["frames_sent"]
    lat = report["latency_ms"]
    assert 0 < lat["p50"] <= lat["p95"] <= lat["p99"] <= lat["max"]
    assert report["metrics_agree"]
    assert report["metrics_delta"]["arcf_results_published_total"] == report["results"]
    for s in report["per_stream"]:
        if s["dropped_by_service"] == 0:  # nothing dropped: identical to the offline run
            assert s["precision20"] == pytest.approx(s["offline_precision20"])
            assert s["auc"] == pytest.approx(s["offline_auc"])
    # the library's own throughput on the same frames, same run: 1 process and 1 per CPU
    assert report["library_fps"] > 0 and report["library_parallel_fps"] > 0
    assert report["processed_fps"] > 0
    assert "| 3 | bacf |" in markdown([report])


def test_looping_replay_reinitialises_and_keeps_the_first_pass_score() -> None:
    """A stream longer than its sequence wraps around; every frame is still accounted for and
    the first pass scores as the offline run does."""
    seqs = load_dataset("uav123_10fps", sequences=["wakeboard7"])  # 67 frames
    svc = ServiceProcess()
    try:
        report = run_load([svc.endpoint], seqs, streams=1, preset="bacf", fps=30.0,
                          duration=8.0, max_frames=90, loop=True, stagger=0.0,
                          metrics_url=svc.metrics_url, service_pid=svc.pid,
                          reference_seconds=0, progress=False)
        control = svc.metric('arcf_control_requests_total')
    finally:
        assert svc.stop() == 0
    assert report["frames_sent"] == 90  # bounded by the frame count, past the sequence's end
    assert report["missing"] == 0
    assert report["results"] + report["dropped_by_service"] == 90
    assert control >= 3  # start, the re-initialisation at the wrap, stop
    s = report["per_stream"][0]
    if s["dropped_by_service"] == 0:
        assert s["precision20"] == pytest.approx(s["offline_precision20"])
        assert s["auc"] == pytest.approx(s["offline_auc"])
    assert report["cpu"]["service_cores"] > 0  # the service's processes were measured
    assert report["breakdown"]["track_ms"] > 0 and report["breakdown"]["decode_ms"] > 0
