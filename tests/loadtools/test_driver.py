"""The stream driver and the results ledger, against an in-process stand-in for the service
(no Zenoh, no worker): schedules, closed loops, holding and releasing, re-initialisation at a
wrap, session bookkeeping and its failures, and the ledger's accounting of what came back.

The schedules themselves are checked exactly on :meth:`Pacing.schedule`; against the clock,
a running stream is only checked for what no machine can excuse (a frame before its slot, a
wait that outlasts what it waits for), since how late a shared machine runs a thread is the
machine's figure."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from arcf.loadtools.driver import GOLDEN, Clip, Fleet, Pacing
from arcf.loadtools.ledger import Ledger, meets_capacity, percentiles
from arcf.loadtools.loadtest import run_load
from arcf.loadtools.waiting import wait_until


def _result(session: str, seq: int, *, dropped: int = 0, status: str = "tracking",
            capture_ns: int | None = None) -> SimpleNamespace:
    return SimpleNamespace(session_id=session, frame_seq=seq, dropped=dropped,
                           status=SimpleNamespace(value=status), box=[1.0, 2.0, 3.0, 4.0],
                           capture_ts_ns=capture_ns if capture_ns is not None else time.time_ns(),
                           track_s=0.004, scale=1.0)


@dataclass
class FakeService:
    """Answers every frame of every session of a stream after ``delay`` s, on its own thread
    (as Zenoh delivers results), unless the frame's number is in ``lose``; ``fail_start`` and
    ``fail_stop`` make the n-th start (1-based) or every stop raise."""

    delay: float = 0.0
    lose: set[int] = field(default_factory=set)
    fail_start: int = 0
    fail_stop: bool = False
    calls: list[tuple[str, Any]] = field(default_factory=list)
    sessions: dict[str, list[str]] = field(default_factory=dict)
    callbacks: dict[str, Any] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def results(self, stream: str, callback: Any = None) -> SimpleNamespace:
        self.callbacks[stream] = callback
        return SimpleNamespace(close=lambda: self._call("unsubscribe", stream))

    def _call(self, kind: str, what: Any) -> None:
        with self.lock:
            self.calls.append((kind, what))

    def start(self, stream: str, box: Any, *, preset: str, frame_seq: int,
              session_id: str | None = None) -> SimpleNamespace:
        starts = sum(1 for c in self.calls if c[0] == "start") + 1
        if starts == self.fail_start:
            raise RuntimeError("limit_exceeded")
        sid = session_id or f"{stream}/{len(self.sessions.get(stream, []))}"
        self.sessions.setdefault(stream, []).append(sid)
        self._call("start", (stream, preset, tuple(box), frame_seq))
        return SimpleNamespace(session_id=sid, message="started")

    def reinit(self, sid: str, box: Any, *, frame_seq: int) -> None:
        self._call("reinit", (sid, frame_seq))

    def stop(self, sid: str) -> None:
        if self.fail_stop:
            raise TimeoutError("no reply")
        self._call("stop", sid)
        for sids in self.sessions.values():
            if sid in sids:
                sids.remove(sid)

    def publish_frame(self, stream: str, *, data: bytes, seq: int,
                      encoding: str = "jpeg") -> None:
        self._call("publish", (stream, seq, time.monotonic()))
        if seq in self.lose:
            return
        captured = time.time_ns()

        def answer() -> None:
            time.sleep(self.delay)
            for sid in self.sessions[stream]:
                self.callbacks[stream](_result(sid, seq, capture_ns=captured))

        threading.Thread(target=answer, daemon=True).start()

    def published(self, stream: str) -> list[tuple[int, float]]:
        return [(c[1][1], c[1][2]) for c in self.calls if c[0] == "publish" and c[1][0] == stream]


def _clip(n: int = 5) -> Clip:
    return Clip("seq", (10.0, 20.0, 30.0, 40.0), tuple(bytes([k]) for k in range(n)))


def _all_answered(st: Any, n: int, timeout: float = 10.0) -> bool:
    return st.record.wait(lambda: len(st.record.received) >= n, timeout)


# ---------------------------------------------------------------------------- schedules
def test_fixed_rate_schedules_spread_phases_from_the_fleet_epoch() -> None:
    pacing = Pacing.fixed_rate(20.0)
    epoch, start = 100.0, 100.123
    for k in range(5):
        due = pacing.schedule(k, epoch, start)
        phase = epoch + ((k * GOLDEN) % 1.0) * 0.05
        assert due(0) >= start - 1e-9 and due(0) - start < 0.05  # the first slot from start
        assert (due(0) - phase) / 0.05 == pytest.approx(round((due(0) - phase) / 0.05))
        assert [due(i) - due(0) for i in range(4)] == pytest.approx([0, 0.05, 0.1, 0.15])
    aligned = Pacing.fixed_rate(20.0, aligned=True)
    assert aligned.schedule(0, epoch, start)(0) == aligned.schedule(3, epoch, start)(0)
    assert aligned.schedule(0, epoch, 100.1)(0) == pytest.approx(100.1)  # on a slot already
    flood = Pacing(fps=0.0)
    assert flood.schedule(2, epoch, start)(7) == start
    with pytest.raises(ValueError):
        Pacing(fps=-1.0)


def test_fixed_rate_streams_keep_their_period() -> None:
    service = FakeService()
    fleet = Fleet(service, [_clip()], pacing=Pacing.fixed_rate(20.0))
    t_add = time.monotonic()
    a, b = fleet.add(2, frames=8)
    assert fleet.wait_published(timeout=30)
    for st in (a, b):
        assert [s for s, _ in st.record.sent] == list(range(8))
        times = [t for _, t in service.published(st.name)]
        assert times == sorted(times)
        # frame i never leaves before its slot on the stream's phase (the slots from the one
        # at or after the stream was added; the stream started at or after that): a stream
        # that ran ahead, or drifted early, fails; a late thread is the machine's figure
        slot = fleet.pacing.schedule(st.index, fleet._epoch, t_add)
        assert all(t >= slot(i) - 1e-3 for i, t in enumerate(times)), (times, slot(0))


def test_delays_staggers_and_holding() -> None:
    service = FakeService()
    fleet = Fleet(service, [_clip()], pacing=Pacing.closed_loop(1))
    held = fleet.add(3, frames=1, stagger=0.15, hold=True)
    time.sleep(0.3)  # the window in which nothing may happen
    assert not any(c[0] == "publish" for c in service.calls)  # held until released
    t0 = fleet.release()
    assert fleet.wait_published(timeout=30)
    firsts = [service.published(st.name)[0][1] - t0 for st in held]
    # in stagger order, none before its delay (how late is the machine's)
    assert 0 <= firsts[0] <= firsts[1] <= firsts[2], firsts
    assert firsts[1] >= 0.15 - 1e-3 and firsts[2] >= 0.3 - 1e-3
    t1 = time.monotonic()
    (late,) = fleet.add(1, frames=1, delay=0.2)
    assert fleet.wait_published(timeout=30)
    assert service.published(late.name)[0][1] - t1 >= 0.2 - 1e-3


# ---------------------------------------------------------------------------- closed loops
def test_closed_loop_keeps_exactly_in_flight_frames_in_the_air() -> None:
    # answers 0.25 s after each frame: long enough that the frame behind it leaves first even
    # on a busy machine, which the overlap count below relies on
    service = FakeService(delay=0.25)
    fleet = Fleet(service, [_clip()], pacing=Pacing.closed_loop(2))
    (st,) = fleet.add(1, sessions=2, frames=12)
    assert fleet.wait_published(timeout=60) and _all_answered(st, 24, timeout=60)
    sent = dict(st.record.sent)
    overlapped = 0
    for k in range(2, 12):
        # never more than two in flight: frame k left only once frame k-2 had both results
        answers_2 = [r.t for r in st.record.received if r.frame_seq == k - 2]
        assert len(answers_2) == 2 and max(answers_2) <= sent[k]
        # and two, not one: frame k usually left before frame k-1 was answered
        answers_1 = [r.t for r in st.record.received if r.frame_seq == k - 1]
        overlapped += sent[k] < min(answers_1)
    assert overlapped >= 5


def test_lock_step_gives_up_on_a_lost_frame_and_pausing_interrupts_the_wait() -> None:
    service = FakeService(lose={3})
    fleet = Fleet(service, [_clip()], pacing=Pacing(fps=0.0, in_flight=1, wait_s=0.3))
    t0 = time.monotonic()
    (st,) = fleet.add(1, frames=6)
    assert fleet.wait_published(timeout=30)
    # frame 4 left only after frame 3's wait (0.3 s) ran out: a lower bound, not a figure
    sent = dict(st.record.sent)
    assert sent[4] - t0 >= 0.3
    assert _all_answered(st, 5)
    assert [r.frame_seq for r in st.record.received] == [0, 1, 2, 4, 5]

    stuck = Fleet(service, [_clip()], pacing=Pacing.lock_step())  # waits up to 30 s
    (blocked,) = stuck.add(1, names=["blocked"], frames=10)
    # frames 0-3 answered at once, then waiting on lost frame 3
    wait_until(lambda: len(service.published("blocked")) == 4, timeout=30,
               what="frames 0-3 published")
    t1 = time.monotonic()
    stuck.pause()
    # the pause interrupted the wait rather than sitting out the lock step's 30 s
    assert time.monotonic() - t1 < Pacing.lock_step().wait_s / 2
    assert [s for s, _ in service.published("blocked")] == [0, 1, 2, 3]  # nothing after pause
    assert not blocked.publishing()


# ---------------------------------------------------------------------------- sessions
def test_wraps_reinitialise_before_the_frame_and_removal_stops_every_session() -> None:
    service = FakeService()
    seen: list[Any] = []
    fleet = Fleet(service, [_clip(3)], preset="bacf", pacing=Pacing.closed_loop(1),
                  on_result=lambda st, got: seen.append(got))
    (st,) = fleet.add(names=["cam"], sessions=["arcf-h", "bacf"], frames=7,
                      reinit_on_wrap=True, session_id=lambda stream, j: f"{stream}-{j}")
    assert fleet.wait_published(timeout=5) and _all_answered(st, 14)
    fleet.close()
    assert st.sessions == ["cam-0", "cam-1"]
    starts = [c[1] for c in service.calls if c[0] == "start"]
    assert [s[1] for s in starts] == ["arcf-h", "bacf"] and starts[0][3] == 0
    order = [(c[0], c[1][1] if c[0] == "publish" else c[1]) for c in service.calls
             if c[0] in ("reinit", "publish")]
    for wrap in (3, 6):  # both sessions re-initialised just before the wrap frame goes out
        at = order.index(("publish", wrap))
        assert order[at - 2:at] == [("reinit", ("cam-0", wrap)), ("reinit", ("cam-1", wrap))]
    assert [c[1] for c in service.calls if c[0] == "stop"] == ["cam-0", "cam-1"]
    assert ("unsubscribe", "cam") in service.calls
    assert fleet.live == [] and fleet.ended == [st]
    assert fleet.sessions_started == fleet.sessions_stopped == 2
    assert sorted(id(x) for x in seen) == sorted(id(x) for x in st.record.received)


def test_remove_takes_the_newest_and_a_failed_start_leaves_nothing_behind() -> None:
    service = FakeService()
    fleet = Fleet(service, [_clip()], pacing=Pacing.fixed_rate(50.0))
    old, mid, new = fleet.add(3)
    fleet.remove(2)
    assert fleet.live == [old] and fleet.ended == [mid, new]
    assert not mid.publishing() and not new.publishing() and old.publishing()
    fleet.close()

    failing = FakeService(fail_start=2)
    fleet = Fleet(failing, [_clip()], pacing=Pacing.fixed_rate(50.0))
    with pytest.raises(RuntimeError, match="limit_exceeded"):
        fleet.add(names=["cam"], sessions=2)
    assert [c for c in failing.calls if c[0] == "stop"] == [("stop", "cam/0")]
    assert ("unsubscribe", "cam") in failing.calls
    assert fleet.live == [] and not any(c[0] == "publish" for c in failing.calls)


def test_a_failed_stop_is_reported_and_the_rest_is_cleaned_up() -> None:
    service = FakeService(fail_stop=True)
    fleet = Fleet(service, [_clip()], pacing=Pacing.fixed_rate(50.0))
    (st,) = fleet.add(names=["cam"], sessions=2)
    fleet.close()
    assert [sid for sid, _ in fleet.stop_errors] == ["cam/0", "cam/1"]
    assert "TimeoutError" in fleet.stop_errors[0][1]
    assert ("unsubscribe", "cam") in service.calls and fleet.live == [] and not st.publishing()


def test_waits_report_what_did_not_happen() -> None:
    service = FakeService(lose={4})
    fleet = Fleet(service, [_clip()], pacing=Pacing.fixed_rate(50.0))
    fleet.add(1, frames=5)
    (endless,) = fleet.add(1)  # no frame count: not waited for
    assert fleet.wait_published(timeout=5)
    assert endless.publishing()
    fleet.pause(streams=[endless])
    assert not fleet.settle(timeout=0.2)  # the last frame (4) is never answered
    fleet.close()


def test_a_stream_id_used_again_gets_a_fresh_record_and_foreign_results_are_ignored() -> None:
    service = FakeService()
    fleet = Fleet(service, [_clip()], pacing=Pacing.closed_loop(1))
    (first,) = fleet.add(names=["cam"], frames=3)
    assert fleet.wait_published(timeout=5) and fleet.settle(timeout=5)
    fleet.close()
    (again,) = fleet.add(names=["cam"], frames=2)
    assert fleet.wait_published(timeout=5) and fleet.settle(timeout=5)
    assert fleet.ledger["cam"] is again.record is not first.record
    again.record.on_result(_result("someone-elses-session", 1))
    assert again.record.foreign == 1 and len(again.record.received) == 2
    assert fleet.ledger.accounting() == {"sessions": 2, "results": 5, "dropped": 0,
                                         "skipped_at_start": 0, "unaccounted": 0,
                                         "out_of_order": 0, "tail": 0, "after_end": 0}


# ---------------------------------------------------------------------------- the ledger
def test_the_ledger_accounts_for_every_frame() -> None:
    ledger = Ledger()
    rec = ledger.open("cam")
    for sid in ("s1", "s2"):
        rec.add_session(sid)
    for k in range(10):
        rec.on_sent(k)
    # s1: skipped frame 0 at the start, frames 4-5 dropped (reported by frame 6), 8-9 queued
    for seq, dropped in ((1, 0), (2, 0), (3, 0), (6, 2), (7, 0)):
        rec.on_result(_result("s1", seq, dropped=dropped))
    # then its stream paused: a stale notice repeats frame 7's number, about no frame
    rec.on_result(_result("s1", 7, status="stale"))
    assert [r.frame_seq for r in rec.stale] == [7] and rec.answered(7) == 1
    # s2: frame 2 lost without a trace, frame 4 arriving after frame 5 (which reports it)
    for seq in (0, 1, 3, 5, 4):
        rec.on_result(_result("s2", seq, dropped=1 if seq == 5 else 0))
    got = rec.accounting()
    assert got == ledger.accounting()
    assert got["sessions"] == 2 and got["results"] == 10
    assert got["skipped_at_start"] == 1 and got["dropped"] == 3
    assert got["out_of_order"] == 1
    assert got["tail"] == (10 - 8) + (10 - 6)  # from the highest frame answered, not the last
    assert got["unaccounted"] == 0 + abs(5 + 1 - 0 - 1 - 5)
    assert rec.gaps(0, time.monotonic() + 1) == 0  # every frame up to 7 answered by someone
    assert rec.answered(1) == 2 and rec.answered(2) == 1 and rec.answered(9) == 0


def test_frames_after_the_service_ended_a_session_are_not_its_tail() -> None:
    """The service sheds a session (its last result, ``stopped``) while the stream goes on:
    the frames sent after that were tracked by nobody, counted apart from the queue's tail."""
    rec = Ledger().open("cam")
    rec.add_session("s1")
    for k in range(4):
        rec.on_sent(k)
        rec.on_result(_result("s1", k))
    rec.on_sent(4)  # in flight when the service ended the session: its tail
    rec.on_result(_result("s1", 3, status="stopped"))
    ended_at = rec.ended[0].t
    wait_until(lambda: time.monotonic() > ended_at, timeout=5,
               what="the clock past the end")  # later frames are sent after the end arrived
    for k in range(5, 9):
        rec.on_sent(k)
    got = rec.accounting()
    assert got["tail"] == 1 and got["after_end"] == 4 and got["unaccounted"] == 0


def test_handover_and_first_resumed() -> None:
    ledger = Ledger()
    rec = ledger.open("cam")
    rec.add_session("s")
    for seq in range(5):
        rec.on_result(_result("s", seq))
    t_event = time.monotonic()
    time.sleep(0.01)  # the stimulus: the resumed result comes 10 ms after the event
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
    rec.add_session("s")
    t0, wall0 = time.monotonic(), time.time_ns()
    for k in range(4):
        rec.on_sent(k)
        rec.on_result(_result("s", k, capture_ns=time.time_ns() - int(0.05e9)))
    w = ledger.window(t0, time.monotonic())
    spent_ms = (time.time_ns() - wall0) / 1e6  # however long this machine took for the loop
    assert w["results"] == 4 and w["dropped"] == 0 and w["errors"] == 0
    # captured 50 ms before it was answered, plus what the loop itself took
    assert 50 <= w["latency_ms"]["p50"] <= w["latency_ms"]["max"] <= 50 + spent_ms
    assert ledger.window(t0 - 10, t0 - 5)["results"] == 0
    assert np.isnan(percentiles([])["p99"])  # nothing measured
    assert meets_capacity(4, 0, 50.0)
    assert not meets_capacity(4, 1, 10.0) and not meets_capacity(0, 0, 10.0)
    assert not meets_capacity(4, 0, 100.0)


def test_clips_play_forward_or_forth_and_back(tmp_path) -> None:
    seq = _sequence(tmp_path, 4)
    assert [f[0] for f in Clip.of(seq, palindrome=True).frames] == [0, 1, 2, 3, 2, 1]
    clip = Clip.of(seq, limit=3)
    assert len(clip) == 3 and clip.groundtruth is not None and clip.groundtruth.shape == (3, 4)


# ---------------------------------------------------------------------------- run_load
def _sequence(tmp_path, n: int, name: str = "s") -> SimpleNamespace:
    frames = []
    for k in range(n):
        p = tmp_path / f"{name}-{k}.jpg"
        p.write_bytes(bytes([k]))
        frames.append(p)
    truth = np.tile([1.0, 2.0, 3.0, 4.0], (n, 1))
    return SimpleNamespace(name=name, init_box=[1, 2, 3, 4], frames=frames, groundtruth=truth)


class _Seq(SimpleNamespace):
    def __len__(self) -> int:
        return len(self.frames)


def test_run_load_reports_what_the_ledger_saw(tmp_path) -> None:
    seqs = [_Seq(**vars(_sequence(tmp_path, 12, name))) for name in ("a", "b")]
    service = FakeService(lose={5})
    report = run_load([], seqs, streams=3, sessions_per_stream=2, fps=50.0, stagger=0.05,
                      duration=5.0, offline=False, reference_seconds=0, progress=False,
                      client=service)
    assert report["streams"] == 3 and report["frames_sent"] == 36
    assert [s["stream"] for s in report["per_stream"]] == ["load-0-a", "load-1-b", "load-2-a"]
    # frame 5 never answered: reported by frame 6's results as nothing (the stand-in does not
    # count drops), so it is missing, twice per stream (two sessions)
    assert report["results"] == 3 * 2 * 11 and report["missing"] == 6
    assert report["dropped_by_service"] == 0
    assert report["per_stream"][0]["precision20"] == pytest.approx(1.0)  # boxes = truth
    assert report["metrics_agree"]  # no metrics URL: nothing to disagree with
    stops = [c[1] for c in service.calls if c[0] == "stop"]
    assert len(stops) == 6  # every session stopped at the end


def test_a_clip_as_video_is_one_access_unit_per_frame_starting_on_a_keyframe(
        wakeboard7) -> None:
    from arcf.client.media.nal import KEYFRAME_TYPES, nal_units
    from arcf.loadtools.video import decode_video

    clip = Clip.of(wakeboard7, limit=12)
    video = clip.as_video("h264")
    assert video.encoding == "h264" and len(video) == len(clip) == 12
    assert video.box == clip.box and video.groundtruth is clip.groundtruth
    assert any(k in KEYFRAME_TYPES["h264"] for k, _ in nal_units(video.frames[0], "h264"))
    pictures = decode_video(video.frames)
    assert len(pictures) == 12 and pictures[0].shape == (720, 1280, 3)


def test_a_clip_as_sent_carries_the_sdks_restart_intervals(wakeboard7) -> None:  # type: ignore[no-untyped-def]
    """``Clip.as_sent``: the same pictures (the SDK's JPEG, quality 90), whose regions a
    worker decodes from the restart intervals around them."""
    from arcf.client.media import _jpegregion
    from arcf.client.media.images import decode_compressed

    clip = Clip.of(wakeboard7, limit=3)
    sent = clip.as_sent()
    assert sent.encoding == "jpeg" and len(sent) == 3 and sent.box == clip.box
    for original, data in zip(clip.frames, sent.frames, strict=True):
        assert data != original
        a, b = decode_compressed(original), decode_compressed(data)
        assert a.shape == b.shape and np.abs(a.astype(int) - b).mean() < 3
        assert _jpegregion.seek(data, 300, 300, 340, 400) == (288, 256)
