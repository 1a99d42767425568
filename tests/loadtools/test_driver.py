"""The stream driver and the results ledger, against an in-process stand-in for the service
(no Zenoh, no worker): pacing, closed loops, re-initialisation at a wrap, session bookkeeping,
and the ledger's accounting of what came back."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from loadtools.driver import GOLDEN, Clip, Fleet, Pacing
from loadtools.ledger import Ledger, meets_capacity, percentiles


def _result(session: str, seq: int, *, dropped: int = 0, status: str = "tracking",
            capture_ns: int | None = None) -> SimpleNamespace:
    return SimpleNamespace(session_id=session, frame_seq=seq, dropped=dropped,
                           status=SimpleNamespace(value=status), box=[1.0, 2.0, 3.0, 4.0],
                           capture_ts_ns=capture_ns if capture_ns is not None else time.time_ns(),
                           track_s=0.004, scale=1.0)


@dataclass
class FakeService:
    """Answers every frame of every session of a stream after ``delay`` s, on its own thread
    (as Zenoh delivers results), unless the frame's number is in ``lose``."""

    delay: float = 0.0
    lose: set[int] = field(default_factory=set)
    calls: list[tuple[str, Any]] = field(default_factory=list)
    sessions: dict[str, list[str]] = field(default_factory=dict)
    callbacks: dict[str, Any] = field(default_factory=dict)
    published: dict[str, list[tuple[int, float]]] = field(default_factory=dict)

    def results(self, stream: str, callback: Any = None) -> SimpleNamespace:
        self.callbacks[stream] = callback
        return SimpleNamespace(close=lambda: self.calls.append(("unsubscribe", stream)))

    def start(self, stream: str, box: Any, *, preset: str, frame_seq: int,
              session_id: str | None = None) -> SimpleNamespace:
        sid = session_id or f"{stream}/{len(self.sessions.get(stream, []))}"
        self.sessions.setdefault(stream, []).append(sid)
        self.calls.append(("start", (stream, preset, tuple(box), frame_seq)))
        return SimpleNamespace(session_id=sid, message="started")

    def reinit(self, sid: str, box: Any, *, frame_seq: int) -> None:
        self.calls.append(("reinit", (sid, frame_seq)))

    def stop(self, sid: str) -> None:
        self.calls.append(("stop", sid))

    def publish_frame(self, stream: str, *, data: bytes, seq: int) -> None:
        self.published.setdefault(stream, []).append((seq, time.monotonic()))
        if seq in self.lose:
            return
        captured = time.time_ns()

        def answer() -> None:
            time.sleep(self.delay)
            for sid in self.sessions[stream]:
                self.callbacks[stream](_result(sid, seq, capture_ns=captured))

        threading.Thread(target=answer, daemon=True).start()


def _clip(n: int = 5) -> Clip:
    return Clip("seq", (10.0, 20.0, 30.0, 40.0), tuple(bytes([k]) for k in range(n)))


def test_fixed_rate_streams_keep_their_period_and_spread_phases() -> None:
    service = FakeService()
    fleet = Fleet(service, [_clip()], pacing=Pacing.fixed_rate(20.0))
    a, b = fleet.add(2, frames=8)
    assert fleet.wait_published(timeout=5) and fleet.settle(timeout=5)
    for st in (a, b):
        times = np.array([t for _, t in st.record.sent])
        assert [s for s, _ in st.record.sent] == list(range(8))
        assert np.allclose(np.diff(times), 0.05, atol=0.02)
    # the two cameras are not synchronised: their frames sit GOLDEN of a period apart
    offset = (b.record.sent[0][1] - a.record.sent[0][1]) % 0.05
    assert offset == pytest.approx((GOLDEN % 1.0) * 0.05, abs=0.01)
    aligned = Fleet(service, [_clip()], pacing=Pacing.fixed_rate(20.0, aligned=True))
    c, d = aligned.add(2, frames=3)
    aligned.wait_published(timeout=5)
    assert abs(c.record.sent[0][1] - d.record.sent[0][1]) < 0.01


def test_closed_loop_never_has_more_frames_in_flight_than_allowed() -> None:
    service = FakeService(delay=0.02)
    fleet = Fleet(service, [_clip()], pacing=Pacing.closed_loop(2))
    (st,) = fleet.add(1, sessions=2, frames=12)
    assert fleet.wait_published(timeout=10) and fleet.settle(timeout=5)
    sent = dict(st.record.sent)
    for k in range(2, 12):  # frame k left only once frame k-2 had both its results
        answers = [r.t for r in st.record.received if r.frame_seq == k - 2]
        assert len(answers) == 2 and max(answers) <= sent[k]
    assert len(st.record.received) == 24


def test_lock_step_waits_for_a_lost_frame_then_goes_on() -> None:
    service = FakeService(lose={3})
    fleet = Fleet(service, [_clip()], pacing=Pacing(fps=0.0, in_flight=1, wait_s=0.3))
    (st,) = fleet.add(1, frames=6)
    t0 = time.monotonic()
    assert fleet.wait_published(timeout=5)
    assert time.monotonic() - t0 >= 0.3  # frame 4 waited for frame 3's answer, then gave up
    assert fleet.settle(timeout=5)
    assert [r.frame_seq for r in st.record.received] == [0, 1, 2, 4, 5]


def test_wraps_reinitialise_and_removal_stops_every_session() -> None:
    service = FakeService()
    fleet = Fleet(service, [_clip(3)], preset="bacf", pacing=Pacing.closed_loop(1))
    (st,) = fleet.add(names=["cam"], sessions=["arcf-h", "bacf"], frames=7,
                      reinit_on_wrap=True, session_id=lambda stream, j: f"{stream}-{j}")
    assert fleet.wait_published(timeout=5)
    fleet.close()
    assert st.sessions == ["cam-0", "cam-1"]
    starts = [c[1] for c in service.calls if c[0] == "start"]
    assert [s[1] for s in starts] == ["arcf-h", "bacf"] and starts[0][3] == 0
    reinits = [c[1] for c in service.calls if c[0] == "reinit"]
    assert reinits == [("cam-0", 3), ("cam-1", 3), ("cam-0", 6), ("cam-1", 6)]
    assert [c[1] for c in service.calls if c[0] == "stop"] == ["cam-0", "cam-1"]
    assert ("unsubscribe", "cam") in service.calls
    assert fleet.live == [] and fleet.ended == [st]
    assert fleet.sessions_started == fleet.sessions_stopped == 2


def test_a_stream_id_used_again_gets_a_fresh_record() -> None:
    service = FakeService()
    fleet = Fleet(service, [_clip()], pacing=Pacing.closed_loop(1))
    (first,) = fleet.add(names=["cam"], frames=3)
    fleet.wait_published(timeout=5)
    fleet.settle(timeout=5)
    fleet.close()
    (again,) = fleet.add(names=["cam"], frames=2)
    fleet.wait_published(timeout=5)
    fleet.settle(timeout=5)
    assert fleet.ledger["cam"] is again.record is not first.record
    assert fleet.ledger.accounting() == {"sessions": 2, "results": 5, "dropped": 0,
                                         "skipped_at_start": 0, "unaccounted": 0,
                                         "out_of_order": 0, "tail": 0}


def test_the_ledger_accounts_for_every_frame() -> None:
    ledger = Ledger()
    rec = ledger.open("cam")
    rec.sessions += ["s1", "s2"]
    for k in range(10):
        rec.on_sent(k)
    # s1: skipped frame 0 at the start, frames 4-5 dropped (reported by frame 6), 8-9 queued
    for seq, dropped in ((1, 0), (2, 0), (3, 0), (6, 2), (7, 0)):
        rec.on_result(_result("s1", seq, dropped=dropped))
    # s2: one result lost without a trace (frame 2), one out of order
    for seq in (0, 1, 3, 5, 4):
        rec.on_result(_result("s2", seq, dropped=1 if seq == 5 else 0))
    got = ledger.accounting()
    assert got["sessions"] == 2 and got["results"] == 10
    assert got["skipped_at_start"] == 1 and got["dropped"] == 3
    assert got["out_of_order"] == 1
    assert got["tail"] == (10 - 8) + (10 - 5)
    assert got["unaccounted"] == 0 + abs(4 + 1 - 0 - 1 - 5)
    assert rec.gaps(0, time.monotonic() + 1) == 0  # every frame up to 7 answered by someone
    assert rec.answered(1) == 2 and rec.answered(2) == 1 and rec.answered(9) == 0


def test_handover_and_first_resumed() -> None:
    ledger = Ledger()
    rec = ledger.open("cam")
    for seq in range(5):
        rec.on_result(_result("s", seq))
    t_event = time.monotonic()
    time.sleep(0.01)
    rec.on_result(_result("s", 8, status="resumed"))
    found = ledger.first_resumed(["cam"], t_event, timeout=1)
    assert set(found) == {"cam"} and found["cam"] > t_event
    lost, ms = rec.handover(t_event)
    assert lost == 3 and ms >= 10
    assert rec.gaps(0, time.monotonic() + 1) == 3  # frames 5-7: no result at all
    assert ledger.first_resumed(["cam"], time.monotonic(), timeout=0.05) == {}


def test_windows_latency_and_the_capacity_criterion() -> None:
    ledger = Ledger()
    rec = ledger.open("cam")
    rec.sessions.append("s")
    t0 = time.monotonic()
    for k in range(4):
        rec.on_sent(k)
        rec.on_result(_result("s", k, capture_ns=time.time_ns() - int(0.05e9)))
    w = ledger.window(t0, time.monotonic())
    assert w["results"] == 4 and w["dropped"] == 0 and w["errors"] == 0
    assert 49 <= w["latency_ms"]["p50"] <= w["latency_ms"]["max"] < 150
    assert ledger.window(t0 - 10, t0 - 5)["results"] == 0
    assert percentiles([])["p99"] != percentiles([])["p99"]  # NaN: nothing measured
    assert meets_capacity(4, 0, w["latency_ms"]["p99"])
    assert not meets_capacity(4, 1, 10.0) and not meets_capacity(0, 0, 10.0)
    assert not meets_capacity(4, 0, 100.0)


def test_pacing_rejects_negative_values_and_clips_play_forth_and_back(tmp_path) -> None:
    with pytest.raises(ValueError):
        Pacing(fps=-1.0)
    frames = []
    for k in range(4):
        p = tmp_path / f"{k}.jpg"
        p.write_bytes(bytes([k]))
        frames.append(p)
    seq = SimpleNamespace(name="s", init_box=[1, 2, 3, 4], frames=frames,
                          groundtruth=np.arange(16.0).reshape(4, 4))
    assert [f[0] for f in Clip.of(seq, palindrome=True).frames] == [0, 1, 2, 3, 2, 1]
    clip = Clip.of(seq, limit=3)
    assert len(clip) == 3 and clip.groundtruth is not None and clip.groundtruth.shape == (3, 4)
