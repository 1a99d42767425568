"""A stream's inbox (the worker's intake queue): newest frames kept, oldest dropped, within a
count that depends on the stream's kind and within a byte cap whatever the count."""

from __future__ import annotations

import threading
import time
from collections import deque
from types import SimpleNamespace

from arcf.schemas import ErrorCode, Frame, decode, encode
from arcf.service.intake import Inbox

KEY = "arcf/v1/streams/cam/frames"
VIDEO_KEY = "video/cam/stream"


class _Counter:
    def labels(self, **_: str) -> _Counter:
        return self

    def inc(self, n: int = 1) -> None:
        pass


METRICS = SimpleNamespace(ERRORS=_Counter(), FRAMES_RECEIVED=_Counter())


class _Payload(bytes):
    def to_bytes(self) -> bytes:
        return bytes(self)


def put(inbox: Inbox, key: str, data: bytes) -> None:
    (inbox.video if key == VIDEO_KEY else inbox)(
        SimpleNamespace(key_expr=key, payload=_Payload(data)))


def inbox(max_payload: int = 1 << 20) -> Inbox:
    return Inbox(KEY, VIDEO_KEY, 2, 60, 1e9, max_payload, threading.Event(), METRICS)


def frame(seq: int, encoding: str, size: int = 100) -> bytes:
    return encode(Frame(stream_id="cam", seq=seq, capture_ts_ns=1, encoding=encoding,
                        payload=b"\x01" * size))


def test_an_image_stream_keeps_its_newest_frames_a_video_stream_every_unit() -> None:
    box = inbox()
    for i in range(10):
        put(box, KEY, frame(i, "jpeg"))
    assert len(box.frames) == 2  # frame_queue
    box = inbox()
    for i in range(50):
        put(box, KEY, frame(i, "h264"))  # recognised from its first unit on
    assert len(box.frames) == 50
    box = inbox()
    for _ in range(70):
        put(box, VIDEO_KEY, b"cdr")
    assert len(box.frames) == 60  # video_queue
    assert [item[3] for item in box.frames] == list(range(10, 70))  # numbered on arrival


def test_frames_too_old_when_their_turn_comes_give_way_to_newer_ones() -> None:
    """``max_age_s``: of an image stream's queued frames, those that arrived longer ago than
    the bound are dropped (counted as trimmed) when a newer one waits; the newest is always
    taken, however old; a video stream's units are all kept."""
    box = Inbox(KEY, VIDEO_KEY, 4, 60, 1e9, 1 << 20, threading.Event(), METRICS,
                max_age_s=0.2)
    for i in range(4):
        put(box, KEY, frame(i, "jpeg"))
    now = time.time_ns()
    # frames 0 and 1 arrived 0.5 s ago, frame 2 0.1 s ago, frame 3 now
    ages = [0.5, 0.5, 0.1, 0.0]
    box.frames = deque((data, now - int(age * 1e9), source, seq)
                       for (data, _, source, seq), age in zip(box.frames, ages, strict=True))
    taken = [decode(box.pop()[0], expected=Frame).seq for _ in range(2)]  # type: ignore[index]
    assert taken == [2, 3] and box.trimmed == 2 and box.pop() is None
    # alone, a frame is taken whatever its age
    put(box, KEY, frame(9, "jpeg"))
    box.frames = deque([(d, now - 10**10, src, q) for d, _, src, q in box.frames])
    assert decode(box.pop()[0], expected=Frame).seq == 9  # type: ignore[index]
    # video units are never dropped for their age: each one is needed to decode the next
    for i in range(3):
        put(box, KEY, frame(10 + i, "h264"))
    box.frames = deque([(d, now - 10**10, src, q) for d, _, src, q in box.frames])
    assert len([box.pop() for _ in range(3)]) == 3 and box.trimmed == 2


def test_a_flood_of_huge_units_stays_within_the_byte_cap() -> None:
    box = inbox(max_payload=8 << 20)
    for i in range(40):
        put(box, KEY, frame(i, "h264", size=7 << 20))
    assert sum(len(item[0]) for item in box.frames) <= box.max_bytes == 32 << 20
    assert len(box.frames) == 4  # the newest ones
    while box.pop() is not None:
        pass
    assert box._bytes == 0


def test_a_stations_history_passes_the_rate_limit_and_gets_room_once() -> None:
    """At subscription a worker asks for a station's recent units (``history``): they come at
    once, so that many pass the rate limit and get places beyond ``video_queue``, given back
    as the loop takes them; the next burst meets the limits again."""
    box = Inbox(KEY, VIDEO_KEY, 2, 60, 30.0, 1 << 20, threading.Event(), METRICS,
                history=150)
    for i in range(150):
        put(box, KEY, frame(i, "h264"))
    assert len(box.frames) == 150 and box.refused[ErrorCode.RATE_LIMITED] == 0
    while box.pop() is not None:
        pass
    assert box.room == 0
    for i in range(150, 250):  # a second burst: 30 frames/s allows a second's worth
        put(box, KEY, frame(i, "h264"))
    assert len(box.frames) == 30 and box.refused[ErrorCode.RATE_LIMITED] == 70
    late = Inbox(KEY, VIDEO_KEY, 2, 60, 30.0, 1 << 20, threading.Event(), METRICS,
                 history=150)
    late.history_until = time.monotonic() - 1  # the history's window has passed
    for i in range(100):
        put(late, KEY, frame(i, "h264"))
    assert late.refused[ErrorCode.RATE_LIMITED] == 70
