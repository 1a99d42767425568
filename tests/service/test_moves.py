"""Streams moved between a service's workers (``--balance-s``; docs/service-design.md,
"Placement by measured cost"), through a real ``arcf-service``: every frame gets exactly one
result, and the results equal the library's offline, bit for bit, across the moves."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

pytest.importorskip("zenoh")

import arcf
from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import next_result, wait_until
from arcf.service.scrape import by_label, fetch

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

STREAMS = ("move-0", "move-1")


def _moves(svc: ServiceProcess) -> dict[str, float]:
    assert svc.metrics_url is not None
    return by_label(fetch(svc.metrics_url), "arcf_stream_moves_total", "outcome")


def test_streams_move_between_workers_and_their_results_do_not_change() -> None:
    """Both workers are told to move a stream every round, whatever it gains (negative
    thresholds), so that each stream moves while its frames flow in lock-step."""
    (seq,) = load_dataset("uav123_10fps", sequences=["truck4_2"])
    data = [p.read_bytes() for p in seq.frames]
    box = tuple(float(v) for v in seq.init_box)
    # lock-step replay runs faster than the per-stream rate limit on a fast machine: lifted
    svc = ServiceProcess("--balance-s", "0.5", "--balance-min-gain", "-1",
                         "--balance-busy-above", "-1", "--max-stream-fps", "10000", workers=2)
    try:
        with TrackingClient(connect=[svc.endpoint], frame_congestion="block") as client:
            queues = {s: client.results(s) for s in STREAMS}
            for s in STREAMS:
                assert client.start(s, box, preset="arcf-h",
                                    overrides={"state.reacquire": True}).session_id
            got: dict[str, list] = {s: [] for s in STREAMS}
            sent = 0
            # frames until two moves were made (a move every round, each stream then settling
            # for 10 s: both streams within a few seconds), bounded by the sequence
            while sent < len(data):
                for s in STREAMS:
                    client.publish_frame(s, data=data[sent], seq=sent)
                for s in STREAMS:
                    got[s].append(next_result(queues[s], sent - 1))
                sent += 1
                if sent % 10 == 0 and _moves(svc).get("moved", 0) >= 2 and sent >= 60:
                    break
            moves = _moves(svc)
        assert moves.get("moved", 0) >= 2, (moves, sent)
        assert moves.get("refused", 0) == 0
    finally:
        svc.stop()
    expected = arcf.run_sequence(arcf.create_tracker("arcf-h", **{"state.reacquire": True}),
                                 (decode_compressed(d) for d in data[:sent]), box).boxes
    for s in STREAMS:
        results = got[s]
        assert [r.frame_seq for r in results] == list(range(sent))  # one each, in order
        assert results[0].status == "initialized"
        assert all(r.status == "tracking" and r.dropped == 0 for r in results[1:])
        np.testing.assert_allclose([r.box for r in results], expected, atol=1e-9)


def test_a_spare_worker_takes_no_new_stream() -> None:
    """``--spare-workers``: a spare runs, and is counted ready, but new streams go to the
    regular workers only (it takes streams moved off an overloaded worker:
    tests/service/test_placement.py has the rule). Shown by killing the spare: no session
    had to be resumed, and every stream goes on."""
    (seq,) = load_dataset("uav123_10fps", sequences=["truck4_2"])
    data = [p.read_bytes() for p in seq.frames[:6]]
    box = tuple(float(v) for v in seq.init_box)
    svc = ServiceProcess("--spare-workers", "1", "--max-stream-fps", "10000", workers=1)
    try:
        assert len(svc.workers) == 2
        spare = sorted(svc.workers)[1]  # spawned after worker 0
        with TrackingClient(connect=[svc.endpoint], frame_congestion="block") as client:
            queues = {s: client.results(s) for s in STREAMS}
            for s in STREAMS:
                client.start(s, box, preset="bacf", frame_seq=0)
            for i, d in enumerate(data):
                if i == 3:
                    os.kill(spare, signal.SIGKILL)
                    wait_until(lambda: svc.metric("arcf_worker_deaths_total") == 1,
                               timeout=60, what="the spare's death counted")
                for s in STREAMS:
                    client.publish_frame(s, data=d, seq=i)
                for s in STREAMS:
                    r = next_result(queues[s], i - 1)
                    assert r.frame_seq == i and r.status.value != "resumed", r
        assert svc.metric("arcf_sessions_taken_over_total") == 0
    finally:
        svc.stop()
