"""A worker's session table: its streams, the sessions on each, and the clocks that end or
warn them (a stream gone silent, a session idle).

Decisions only: the table says which session is stale or expired and why; the worker
publishes the notices and ends the sessions (:mod:`arcf.service.worker`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

from .commands import SessionStat
from .streams import Session, Stream


@dataclass(frozen=True)
class StaleNotice:
    """A session whose stream delivered nothing for ``stale_after_s``: its notice's text,
    and whether this is the first since it last had a frame (counted once)."""

    session: Session
    why: str
    silent_s: float
    first: bool


class SessionTable:
    """The streams a worker owns and their sessions, by id."""

    def __init__(self) -> None:
        self.streams: dict[str, Stream] = {}
        self.sessions: dict[str, Session] = {}

    def __len__(self) -> int:
        return len(self.sessions)

    def __iter__(self) -> Iterator[Session]:
        return iter(list(self.sessions.values()))

    def get(self, session_id: str) -> Session | None:
        return self.sessions.get(session_id)

    def add(self, session: Session, stream: Stream) -> None:
        """Add a session on ``stream`` (the stream joins the table with its first session)."""
        self.streams.setdefault(stream.stream_id, stream)
        stream.sessions[session.session_id] = session
        self.sessions[session.session_id] = session

    def remove(self, session_id: str) -> tuple[Session | None, Stream | None]:
        """Take a session out; with it, its stream if no session is left on it (for the
        caller to undeclare): (session or None, emptied stream or None)."""
        s = self.sessions.pop(session_id, None)
        if s is None:
            return None, None
        stream = self.streams[s.stream_id]
        stream.sessions.pop(session_id, None)
        if stream.sessions:
            return s, None
        del self.streams[stream.stream_id]
        return s, stream

    def discard_stream(self, stream: Stream) -> None:
        """Forget a stream that no session could start on."""
        if not stream.sessions:
            self.streams.pop(stream.stream_id, None)

    def frame_seq_problem(self, stream_id: str, frame_seq: int | None,
                          max_seq_gap: int) -> str | None:
        """Why a box for ``frame_seq`` is refused: a frame far beyond the stream's last one
        might never come (a box for a past frame applies to the next frame, and its result
        says so). None when it is accepted."""
        stream = self.streams.get(stream_id)
        last = stream.numbering.last if stream is not None else None
        if frame_seq is not None and last is not None and frame_seq > last + max_seq_gap:
            return (f"frame_seq {frame_seq} is more than {max_seq_gap} frames after the "
                    f"stream's last frame {last}")
        return None

    def stale(self, now: float, after: float) -> tuple[list[StaleNotice], float]:
        """The sessions whose stream delivered no frame for ``after`` seconds (again every
        ``after`` while it lasts), marked as noticed; and the monotonic time to look again
        (inf: nothing can go stale).

        A session's clock runs from the later of its last result about a frame (or its
        start) and its stream's last arrival, so a worker busy with other streams, or a frame
        taking longer than ``after`` to track, does not make a stream that delivers look
        stale; frames waiting in the inbox mean the same. Cheap: a few comparisons per
        session, run when the earliest deadline passes, not on a fixed tick."""
        due = math.inf
        notices: list[StaleNotice] = []
        if not after:
            return notices, due
        for s in self:
            stream = self.streams.get(s.stream_id)
            if stream is None:
                continue
            if stream.inbox.frames:  # frames are waiting: the loop gets to them this round
                due = min(due, now + after / 10)  # and this looks again soon after
                continue
            since = max(s.fresh_at, stream.inbox.arrived)
            at = since + after if s.stale_noticed is None else max(since, s.stale_noticed) + after
            if now >= at:
                if s.last_seq is None:
                    why = (f"no frame of stream {s.stream_id!r} for {now - since:.1f} s since "
                           "the session started")
                else:
                    why = (f"no frame of stream {s.stream_id!r} for {now - since:.1f} s: the "
                           f"box of frame {s.last_seq} is not current")
                notices.append(StaleNotice(s, why, now - since, s.stale_noticed is None))
                s.stale_noticed = now
                at = now + after
            due = min(due, at)
        return notices, due

    def expired(self, now: float, idle: float) -> list[tuple[Session, str]]:
        """The sessions idle past ``idle`` seconds, with why (no frame; or no frame at or
        after the one their box was drawn on)."""
        out = []
        for s in self:
            if now - s.last_activity <= idle:
                continue
            if s.tracker.initialized and s.pending_box is None:
                why = f"no frame of stream {s.stream_id!r} for {idle:g} s"
            else:
                after = "the next frame" if s.pending_seq is None else f"frame {s.pending_seq}"
                why = f"waited {idle:g} s for {after} of stream {s.stream_id!r}"
            out.append((s, f"session ended: {why}"))
        return out

    def stats(self) -> dict[str, SessionStat]:
        return {sid: s.stat() for sid, s in self.sessions.items()}
