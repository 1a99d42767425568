"""Frames on streams nobody tracks are told so (``no_session``) by either source the service
uses (:mod:`arcf.service.untracked`): each frame's key through the embedded router, or the
stations' publisher tokens elsewhere. A fake session records what is put; no network."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import zenoh

from arcf.schemas import ErrorMessage, KeySpace, decode
from arcf.service import metrics
from arcf.service.untracked import UntrackedNotices

KEYS = KeySpace()


class _Session:
    def __init__(self) -> None:
        self.puts: list[tuple[str, ErrorMessage]] = []

    def put(self, key: str, payload: bytes, **_: Any) -> None:
        self.puts.append((key, decode(payload, expected=ErrorMessage)))


def _sample(key: str, kind: Any = None) -> Any:
    return SimpleNamespace(key_expr=key, kind=kind or zenoh.SampleKind.PUT)


def _told(session: _Session) -> list[str]:
    return [m.stream_id for _, m in session.puts if m.code == "no_session"]


def test_frames_through_the_router_are_counted_and_told_once_a_second() -> None:
    session = _Session()
    notices = UntrackedNotices(session, KEYS, lambda: {"tracked"}, metrics)
    before = metrics.ERRORS.labels(kind="no_session")._value.get()
    for _ in range(3):
        notices._on_frame(_sample(KEYS.frames("lost")))
        notices._on_frame(_sample(KEYS.frames("tracked")))
    notices._on_frame(_sample("arcf/v1/not/a/frames/key"))
    assert _told(session) == ["lost"]  # once, though three frames came
    assert session.puts[0][0] == KEYS.errors("lost")
    assert metrics.ERRORS.labels(kind="no_session")._value.get() - before == 3  # each frame


def test_announced_streams_are_told_by_their_owner_while_untracked() -> None:
    session = _Session()
    tracked: set[str] = {"busy"}
    notices = UntrackedNotices(session, KEYS, lambda: tracked, metrics,
                               mine=lambda stream: stream != "elsewhere")
    for stream in ("idle", "busy", "elsewhere"):
        notices._on_publisher(_sample(KEYS.publisher_token(stream, "st-1")))
    notices._on_publisher(_sample("arcf/v1/publishers/*/x"))  # not a token key: ignored
    notices.tick()
    assert _told(session) == ["idle"]  # not the tracked one, nor one another instance owns
    notices.tick()
    assert _told(session) == ["idle"]  # at most once a second
    notices.told.clear()  # as if a second passed
    tracked.add("idle")  # a session started: no more notices
    notices.tick()
    assert _told(session) == ["idle"]
    tracked.discard("idle")
    notices._on_publisher(_sample(KEYS.publisher_token("idle", "st-1"),
                                  zenoh.SampleKind.DELETE))  # the station stopped publishing
    notices.tick()
    assert _told(session) == ["idle"] and "idle" not in notices.announced
