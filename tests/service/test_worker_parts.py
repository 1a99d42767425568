"""A worker's parts on their own, without Zenoh: the session table's clocks, the turn budget's
shedding, and the frame pipeline on real JPEG and H.264 payloads."""

from __future__ import annotations

import threading
from collections import deque
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from prometheus_client import REGISTRY

from arcf.client.media.encodings import encode_image
from arcf.region import RegionFrame
from arcf.schemas import ErrorCode, ErrorMessage, Frame, Result, decode, encode
from arcf.service import metrics
from arcf.service.intake import Inbox, Numbering
from arcf.service.pipeline import FramePipeline
from arcf.service.sessions import SessionTable
from arcf.service.settings import ServiceSettings
from arcf.service.stages import StageClock
from arcf.service.streams import Session, Stream
from arcf.service.turns import OVER_BUDGET_WINDOWS, TurnBudget


class _Errors:
    """A stream's error key: the notices put on it."""

    def __init__(self) -> None:
        self.sent: list[ErrorMessage] = []

    def put(self, data: bytes) -> None:
        self.sent.append(decode(data, expected=ErrorMessage))


def _inbox() -> SimpleNamespace:
    return SimpleNamespace(frames=deque(), arrived=0.0, trimmed=0)


def _stream(stream_id: str, inbox: Any = None) -> Stream:
    return Stream(stream_id, None, inbox if inbox is not None else _inbox(), _Errors(),
                  Numbering(300, 3, rate=60.0))


def _session(sid: str, stream_id: str, *, initialized: bool = True,
             at: float = 0.0) -> Session:
    tracker = SimpleNamespace(initialized=initialized, read_region=lambda: None)
    return Session(sid, stream_id, "arcf-h", tracker, None, last_activity=at, fresh_at=at)


# ---------------------------------------------------------------------- the session table
def test_a_stream_leaves_the_table_with_its_last_session() -> None:
    table = SessionTable()
    a, b = _stream("a"), _stream("b")
    table.add(_session("1", "a"), a)
    table.add(_session("2", "a"), a)
    table.add(_session("3", "b"), b)
    assert len(table) == 3 and set(table.streams) == {"a", "b"}
    first = table.get("1")
    assert first is not None and table.remove("1") == (first, None)  # "a" still has "2"
    s, emptied = table.remove("2")
    assert s is not None and s.session_id == "2" and emptied is a
    assert set(table.streams) == {"b"} and table.remove("2") == (None, None)


def test_a_box_for_a_frame_too_far_ahead_is_refused() -> None:
    table = SessionTable()
    stream = _stream("a")
    table.add(_session("1", "a"), stream)
    assert table.frame_seq_problem("a", 500, 300) is None  # no frame seen yet
    stream.numbering.admit(100, 0.0)
    assert table.frame_seq_problem("a", 400, 300) is None
    assert table.frame_seq_problem("a", 401, 300) == (
        "frame_seq 401 is more than 300 frames after the stream's last frame 100")
    assert table.frame_seq_problem("unknown", 10**6, 300) is None


def test_stale_notices_come_once_per_period_and_say_why() -> None:
    table = SessionTable()
    quiet, busy = _stream("quiet"), _stream("busy")
    table.add(_session("q", "quiet", at=0.0), quiet)
    table.add(_session("b", "busy", at=0.0), busy)
    busy.inbox.frames.append((b"", 0, "frame", None))  # frames waiting: never stale
    notices, due = table.stale(1.0, 2.0)
    assert notices == [] and due == pytest.approx(1.2)  # looks again soon for "busy"
    notices, due = table.stale(2.5, 2.0)
    assert [(n.session.session_id, n.first) for n in notices] == [("q", True)]
    assert notices[0].why == ("no frame of stream 'quiet' for 2.5 s since the session started")
    assert table.stale(3.0, 2.0)[0] == []  # told at 2.5: again at 4.5, no earlier
    again, _ = table.stale(4.6, 2.0)
    assert [(n.session.session_id, n.first) for n in again] == [("q", False)]
    assert table.stale(5.0, 0.0) == ([], float("inf"))  # stale_after_s 0: never


def test_idle_sessions_expire_with_their_reason() -> None:
    table = SessionTable()
    table.add(_session("on", "a", at=0.0), _stream("a"))
    waiting = _session("wait", "b", initialized=False, at=0.0)
    waiting.pending_box, waiting.pending_seq = (1.0, 1.0, 5.0, 5.0), 40
    table.add(waiting, _stream("b"))
    table.add(_session("new", "c", at=50.0), _stream("c"))
    assert sorted((s.session_id, why) for s, why in table.expired(60.0, 30.0)) == [
        ("on", "session ended: no frame of stream 'a' for 30 s"),
        ("wait", "session ended: waited 30 s for frame 40 of stream 'b'")]
    assert set(table.stats()) == {"on", "wait", "new"}


# ---------------------------------------------------------------------- the turn budget
def _window(stream: Stream, decode_s: float, turns: int, *cpu: float,
            waited: float = 0.0) -> None:
    stream.window_decode_s, stream.window_turns, stream.window_wait_s = decode_s, turns, waited
    for s, c in zip(stream.sessions.values(), cpu, strict=True):
        s.window_cpu_s = c


def _two_streams() -> tuple[SessionTable, Stream, Stream]:
    table = SessionTable()
    heavy, light = _stream("heavy"), _stream("light")
    for sid in ("h1", "h2", "h3"):
        table.add(_session(sid, "heavy"), heavy)
    table.add(_session("l1", "light"), light)
    return table, heavy, light


def test_a_stream_that_starves_another_loses_its_costliest_sessions() -> None:
    table, heavy, light = _two_streams()
    budget = TurnBudget(0.8)
    shed: list[Any] = []
    for _ in range(OVER_BUDGET_WINDOWS):
        assert shed == []  # one window over budget is noise
        _window(heavy, 0.01, 10, 0.30, 0.20, 0.01)
        _window(light, 0.01, 10, 0.02, waited=0.3)
        shed = budget.window(table.streams.values(), busy=0.95, window_s=1.0)
    # heavy's turn 52 ms against light's 3 ms (fair: 6 ms): its two costliest sessions go,
    # which leaves 2 ms
    assert [(x.session.session_id, x.cause) for x in shed] == [
        ("h1", "tracking"), ("h2", "tracking")]
    assert shed[0].why.startswith("session ended: its tracking took 300 ms of CPU a second, "
                                  "on stream 'heavy', the most on a worker 95 % busy")
    assert heavy.window_turns == 0 and all(s.window_cpu_s == 0 for s in table)


def test_equals_and_a_worker_within_budget_shed_nothing() -> None:
    table, heavy, light = _two_streams()
    budget = TurnBudget(0.8)
    for _ in range(3 * OVER_BUDGET_WINDOWS):
        _window(heavy, 0.01, 10, 0.30, 0.20, 0.05)
        _window(light, 0.01, 10, 0.02, waited=0.3)
        assert budget.window(table.streams.values(), busy=0.5, window_s=1.0) == []
    for _ in range(3 * OVER_BUDGET_WINDOWS):  # over budget, but nothing waits
        _window(heavy, 0.01, 10, 0.30, 0.20, 0.05)
        _window(light, 0.01, 10, 0.02)
        assert budget.window(table.streams.values(), busy=0.95, window_s=1.0) == []


def test_a_stream_too_costly_to_decode_loses_every_session() -> None:
    table, heavy, light = _two_streams()
    budget = TurnBudget(0.8)
    for _ in range(OVER_BUDGET_WINDOWS):
        _window(heavy, 0.6, 10, 0.05, 0.04, 0.03)
        _window(light, 0.01, 10, 0.02, waited=0.3)
        shed = budget.window(table.streams.values(), busy=0.95, window_s=1.0)
    assert sorted((x.session.session_id, x.cause) for x in shed) == [
        ("h1", "decoding"), ("h2", "decoding"), ("h3", "decoding")]
    assert "decoding stream 'heavy' took 600 ms of CPU a second (60 ms a turn)" in shed[0].why


# ---------------------------------------------------------------------- the frame pipeline
def _errors(kind: ErrorCode) -> float:
    return REGISTRY.get_sample_value("arcf_errors_total", {"kind": kind.value}) or 0.0


@pytest.fixture
def pipeline() -> FramePipeline:
    return FramePipeline(ServiceSettings(max_pixels=1280 * 720), metrics,
                         StageClock(metrics.STAGE_CPU))


def _real_stream(stream_id: str = "cam") -> Stream:
    inbox = Inbox(f"arcf/v1/frames/{stream_id}", None, 4, 64, 1000.0, 1 << 24,
                  threading.Event(), metrics)
    return _stream(stream_id, inbox)


def _frame(stream_id: str, seq: int, payload: bytes, encoding: str = "jpeg") -> bytes:
    return encode(Frame(stream_id=stream_id, seq=seq, capture_ts_ns=1000 + seq,
                        encoding=encoding, payload=payload))


def test_a_jpeg_frame_is_decoded_where_the_trackers_read(pipeline: FramePipeline,
                                                         wakeboard7) -> None:  # type: ignore[no-untyped-def]
    from arcf.client.media.images import REGION_DECODING

    jpeg = wakeboard7.frames[0].read_bytes()
    stream = _real_stream()
    tracker = SimpleNamespace(initialized=True, read_region=lambda: (300, 500, 400, 640))
    stream.sessions["s"] = Session("s", "cam", "arcf-h", tracker, None)
    picture = pipeline.take(stream, _frame("cam", 7, jpeg), 5)
    assert picture is not None and picture.seq == 7 and picture.capture_ts_ns == 1007
    image = picture.pixels(None)
    whole = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    if REGION_DECODING:
        assert isinstance(image, RegionFrame)
        t, lf, b, r = image.region
        assert t <= 300 and lf <= 500 and b >= 400 and r >= 640
        assert np.array_equal(image.pixels[300:400, 500:640], whole[300:400, 500:640])
    else:
        assert isinstance(image, np.ndarray) and image.shape == whole.shape


def test_refused_frames_are_counted_and_told(pipeline: FramePipeline) -> None:
    stream = _real_stream()
    jpeg = encode_image(np.zeros((16, 16, 3), np.uint8), "jpeg")
    before = {k: _errors(k) for k in (ErrorCode.INVALID_KEY, ErrorCode.STALE_FRAME,
                                      ErrorCode.IMAGE_TOO_LARGE)}
    assert pipeline.take(stream, _frame("other", 1, jpeg), 0) is None
    assert pipeline.take(stream, _frame("cam", 5, jpeg), 0) is not None
    assert pipeline.take(stream, _frame("cam", 5, jpeg), 0) is None  # a duplicate
    bomb = encode_image(np.zeros((800, 1700), np.uint8), "png")  # 1.36 MP > 0.92 MP
    refused = pipeline.take(stream, _frame("cam", 6, bomb, "png"), 0)
    assert refused is not None and not refused.has_pixels
    assert refused.code is ErrorCode.IMAGE_TOO_LARGE
    for code in before:
        assert _errors(code) == before[code] + 1, code
    told = [(e.code, e.frame_seq) for e in stream.errors.sent]
    assert told == [(ErrorCode.INVALID_KEY, 1), (ErrorCode.STALE_FRAME, 5),
                    (ErrorCode.IMAGE_TOO_LARGE, 6)]


def test_a_box_drawn_before_a_camera_restart_applies_after_it(pipeline: FramePipeline) -> None:
    """A station draws a box on frame 5000 as its camera restarts and numbers from 0: once
    the stream follows the new numbering (resync_frames frames in a row), the waiting box
    applies to the first frame of it, instead of waiting for frame 5000 for good."""
    stream = _real_stream()
    jpeg = encode_image(np.zeros((16, 16, 3), np.uint8), "jpeg")
    assert pipeline.take(stream, _frame("cam", 4999, jpeg), 0) is not None
    waiting = Session("w", "cam", "arcf-h", None, None, pending_box=(1.0, 1.0, 4.0, 4.0),
                      pending_seq=5000)
    later = Session("l", "cam", "arcf-h", None, None, pending_box=(1.0, 1.0, 4.0, 4.0),
                    pending_seq=1)  # drawn on the new feed's frame 1: still waits for it
    stream.sessions.update(w=waiting, l=later)
    taken = [pipeline.take(stream, _frame("cam", seq, jpeg), 0) for seq in range(3)]
    assert [p is not None for p in taken] == [False, False, True]  # followed at the 3rd
    assert [(e.code, e.frame_seq) for e in stream.errors.sent][-1] == (
        ErrorCode.SEQUENCE_RESTARTED, 2)
    assert (waiting.pending_seq, later.pending_seq) == (2, 1)


def test_video_units_go_through_the_streams_decoder(pipeline: FramePipeline,
                                                    wakeboard7) -> None:  # type: ignore[no-untyped-def]
    from arcf.loadtools.video import encode_video

    images = [cv2.resize(cv2.imread(str(p)), (320, 180)) for p in wakeboard7.frames[:6]]
    units = encode_video(images, "h264", gop=3)
    stream = _real_stream()
    out = [pipeline.take(stream, _frame("cam", i, u, "h264"), 0) for i, u in enumerate(units)]
    pictures = [p for p in out if p is not None]
    assert [p.seq for p in pictures] == list(range(6))
    first = pictures[0].pixels(None)
    assert isinstance(first, np.ndarray) and first.shape == (180, 320, 3)
    # a lost unit: the decoder waits for the next keyframe (unit 6 of a second stream's run)
    more = encode_video(images, "h264", gop=3)
    before = _errors(ErrorCode.DECODE_ERROR)
    gap = pipeline.take(stream, _frame("cam", 8, more[1], "h264"), 0)  # 7 never came
    assert gap is not None and gap.code is ErrorCode.DECODE_ERROR
    assert _errors(ErrorCode.DECODE_ERROR) == before + 1
    resumed = pipeline.take(stream, _frame("cam", 9, more[3], "h264"), 0)  # a keyframe
    assert resumed is not None and resumed.has_pixels and resumed.seq == 9


def test_decoders_reset_say_why(pipeline: FramePipeline, wakeboard7) -> None:  # type: ignore[no-untyped-def]
    from arcf.loadtools.video import encode_video

    images = [cv2.resize(cv2.imread(str(p)), (320, 180)) for p in wakeboard7.frames[:2]]
    stream = _real_stream()
    for i, unit in enumerate(encode_video(images, "h264")):
        pipeline.take(stream, _frame("cam", i, unit, "h264"), 0)
    assert stream.decoder is not None
    assert pipeline.reset_decoders([stream, _real_stream("idle")], "memory", "memory") == 1
    assert stream.decoder is None and stream.errors.sent[-1].message == "memory"


# ---------------------------------------------------------------------- tracking
class _Results:
    """A session's result key: the results put on it."""

    def __init__(self) -> None:
        self.sent: list[Result] = []

    def put(self, data: bytes) -> None:
        self.sent.append(decode(data, expected=Result))


def _tracked_session(sid: str, box: Any, preset: str = "arcf-h") -> Session:
    from arcf import create_tracker

    return Session(sid, "cam", preset, create_tracker(preset), _Results(), pending_box=box)


def test_sessions_start_on_their_frame_track_and_end_when_their_box_is_absurd(
        wakeboard7) -> None:  # type: ignore[no-untyped-def]
    from arcf.service.streams import Picture
    from arcf.service.tracking import Tracking

    stream = _stream("cam")
    good = _tracked_session("good", tuple(wakeboard7.groundtruth[0]))
    late = _tracked_session("late", tuple(wakeboard7.groundtruth[0]))
    late.pending_seq = 2  # drawn on frame 2: waits for it
    absurd = _tracked_session("absurd", (5000.0, 5000.0, 10.0, 10.0))
    for s in (good, late, absurd):
        stream.sessions[s.session_id] = s
    tracking = Tracking(metrics, StageClock(metrics.STAGE_CPU), session_budget_s=10.0)
    ends = []
    for seq in range(4):
        image = cv2.imread(str(wakeboard7.frames[seq]))
        ends += tracking.run(stream, Picture(seq, 100 + seq, 200 + seq, 0.001, image))
    assert [(e.session.session_id, e.code) for e in ends] == [("absurd", ErrorCode.INVALID_BOX)]
    assert "its box does not fit frame 0" in ends[0].why
    assert [(r.frame_seq, r.status) for r in good.publisher.sent] == [
        (0, "initialized"), (1, "tracking"), (2, "tracking"), (3, "tracking")]
    assert [(r.frame_seq, r.status) for r in late.publisher.sent] == [
        (2, "initialized"), (3, "tracking")]
    assert [(r.frame_seq, r.status, r.code) for r in absurd.publisher.sent] == [
        (0, "error", ErrorCode.INVALID_BOX)]
    last = good.publisher.sent[-1]
    assert last.capture_ts_ns == 103 and last.received_ts_ns == 203 and last.dropped == 0
    assert last.track_state == "tracking" and 0.0 < (last.confidence or 0.0) <= 1.0
    # a picture that could not be decoded: every session told, with its code
    stream.sessions.pop("absurd")
    ends = tracking.run(stream, Picture(5, 105, 205, 0.0, None, ErrorCode.DECODE_ERROR, "bad"))
    assert ends == []
    assert [(r.frame_seq, r.status, r.code, r.message, r.dropped)
            for r in (good.publisher.sent[-1], late.publisher.sent[-1])] == [
        (5, "error", ErrorCode.DECODE_ERROR, "bad", 1)] * 2


def test_a_session_over_its_budget_is_returned_to_end(wakeboard7) -> None:  # type: ignore[no-untyped-def]
    from arcf.service.streams import Picture
    from arcf.service.tracking import Tracking

    stream = _stream("cam")
    s = _tracked_session("costly", tuple(wakeboard7.groundtruth[0]))
    stream.sessions[s.session_id] = s
    tracking = Tracking(metrics, StageClock(metrics.STAGE_CPU), session_budget_s=1e-6)
    image = cv2.imread(str(wakeboard7.frames[0]))
    ends = tracking.run(stream, Picture(0, 1, 1, 0.0, image))
    assert [(e.session.session_id, e.code) for e in ends] == [
        ("costly", ErrorCode.LIMIT_EXCEEDED)]
    assert "budget of a session (session_budget_ms)" in ends[0].why


def test_a_box_drawn_on_a_passed_video_picture_starts_there_and_catches_up(
        pipeline: FramePipeline, wakeboard7) -> None:  # type: ignore[no-untyped-def]
    """Keyframes every 5 frames; the worker has decoded up to frame 13 when the boxes come.
    A box drawn on frame 11 (this group) or 8 (the group before) is applied to that very
    picture, decoded again from its group's keyframe, and the session tracks every picture
    since: the boxes a tracker started there on the plainly decoded video gives. A box
    drawn before the two kept groups (frame 3) applies to the next picture, saying so, as
    does a box re-drawn on a frame the track has answered (no frame is answered twice); and
    no session gets a result before the frame it was drawn on."""
    from arcf import create_tracker
    from arcf.loadtools.video import decode_video, encode_video
    from arcf.service.tracking import Tracking

    images = [cv2.imread(str(p)) for p in wakeboard7.frames[:17]]
    units = encode_video(images, "h264", gop=5)
    stream = _real_stream()
    tracking = Tracking(metrics, StageClock(metrics.STAGE_CPU), session_budget_s=10.0)
    for i in range(14):
        picture = pipeline.take(stream, _frame("cam", i, units[i], "h264"), 0)
        assert picture is not None and tracking.run(stream, picture) == []
    boxes = {i: tuple(float(v) for v in wakeboard7.groundtruth[i]) for i in (3, 8, 11, 17)}
    sessions = {}
    for name, drawn in (("drawn", 11), ("across", 8), ("early", 3), ("ahead", 17)):
        sessions[name] = _tracked_session(name, boxes[drawn])
        sessions[name].pending_seq = drawn
    stream.sessions.update(sessions)
    before = REGISTRY.get_sample_value("arcf_video_replayed_pictures_total") or 0.0
    live = pipeline.take(stream, _frame("cam", 14, units[14], "h264"), 0)
    assert live is not None and tracking.run(stream, live) == []
    assert (REGISTRY.get_sample_value("arcf_video_replayed_pictures_total") or 0.0) == (
        before + 3 + 6)  # 11-13 and 8-13
    # the pilot re-draws on frame 12, which the track has answered: it goes on from 15
    early = sessions["early"]
    early.pending_box, early.pending_seq, early.pending_status = boxes[11], 12, "reinitialized"
    nxt = pipeline.take(stream, _frame("cam", 15, units[15], "h264"), 0)
    assert nxt is not None and tracking.run(stream, nxt) == []
    broken = pipeline.take(stream, _frame("cam", 16, units[16][:40], "h264"), 0)
    assert broken is not None and broken.code is ErrorCode.DECODE_ERROR
    assert tracking.run(stream, broken) == []
    sent = {name: s.publisher.sent for name, s in sessions.items()}
    for name, drawn in (("drawn", 11), ("across", 8)):
        assert [(r.frame_seq, r.status, r.message) for r in sent[name]] == [
            (drawn, "initialized", None),
            *((i, "tracking", None) for i in range(drawn + 1, 16)), (16, "error", broken.text)]
        reference = create_tracker("arcf-h")
        plain = decode_video(units)
        want = [reference.init(plain[drawn], boxes[drawn]).box] + [
            reference.update(plain[i]).box for i in range(drawn + 1, 16)]
        assert [tuple(r.box) for r in sent[name][:-1]] == [tuple(b) for b in want], name
    assert [(r.frame_seq, r.status) for r in sent["early"]] == [
        (14, "initialized"), (15, "reinitialized"), (16, "error")]
    assert sent["early"][0].message == ("box of frame 3 applied to frame 14, the first this "
                                        "session saw at or after it")
    assert "box of frame 12 applied to frame 15" in (sent["early"][1].message or "")
    assert sent["ahead"] == []
