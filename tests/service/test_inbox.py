"""A stream's inbox (the worker's intake queue): newest frames kept, oldest dropped, within a
count that depends on the stream's kind and within a byte cap whatever the count."""

from __future__ import annotations

import threading
from types import SimpleNamespace

from arcf.schemas import Frame, encode
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


def test_a_flood_of_huge_units_stays_within_the_byte_cap() -> None:
    box = inbox(max_payload=8 << 20)
    for i in range(40):
        put(box, KEY, frame(i, "h264", size=7 << 20))
    assert sum(len(item[0]) for item in box.frames) <= box.max_bytes == 32 << 20
    assert len(box.frames) == 4  # the newest ones
    while box.pop() is not None:
        pass
    assert box._bytes == 0
