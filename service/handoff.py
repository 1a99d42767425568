"""A stream's state, handed from one worker process to another (:mod:`arcf.service.placement`
moves streams between the workers of one instance).

What moves is what the results depend on: each session's tracker, exactly as it is (its
model, its filter, its track state: the next result is the one the old worker would have
given), what it waits for (a box not applied yet), its frame counters, and the stream's
numbering. The Zenoh declarations, the queue and the decoder stay behind: the new worker
declares its own. Trackers that cannot be pickled (OpenCV's networks) make a stream
unmovable; video streams are not moved either (the new worker's decoder would wait for the
next keyframe, and the frames until then would get no result).

The state travels as the commands do, between the processes of one instance over the queues
of ``multiprocessing`` (which pickle what they carry): never from the network.
"""

from __future__ import annotations

from dataclasses import dataclass
from multiprocessing.reduction import ForkingPickler
from typing import Any

from .intake import Numbering
from .streams import Session, Stream


@dataclass(frozen=True)
class SessionState:
    session_id: str
    preset: str
    tracker: Any
    pending_box: tuple[float, float, float, float] | None
    pending_seq: int | None
    pending_status: str
    last_seq: int | None
    frames: int
    last_result_ns: int | None
    cost_s: float
    tracked: int
    last_box: tuple[int, tuple[float, float, float, float]] | None

    @classmethod
    def of(cls, s: Session) -> SessionState:
        return cls(s.session_id, s.preset, s.tracker, s.pending_box, s.pending_seq,
                   s.pending_status, s.last_seq, s.frames, s.last_result_ns, s.cost_s, s.tracked,
                   s.last_box)

    def session(self, stream_id: str, publisher: Any) -> Session:
        """The session again, publishing through ``publisher``."""
        return Session(self.session_id, stream_id, self.preset, self.tracker, publisher,
                       pending_box=self.pending_box, pending_seq=self.pending_seq,
                       pending_status=self.pending_status, last_seq=self.last_seq,
                       frames=self.frames, last_result_ns=self.last_result_ns,
                       cost_s=self.cost_s, tracked=self.tracked, last_box=self.last_box)


@dataclass(frozen=True)
class StreamState:
    stream_id: str
    numbering: Numbering
    sessions: tuple[SessionState, ...]


def portable(tracker: Any) -> bool:
    """Whether a tracker's state can be handed over: whether the queues between the
    instance's processes can carry it."""
    try:
        ForkingPickler.dumps(tracker)
    except Exception:  # TypeError, PicklingError, ...: whatever the pickler refuses
        return False
    return True


def movable(stream: Stream) -> bool:
    """Whether a stream can move (frames, not video; every tracker portable, as checked once
    per session)."""
    if stream.decoder is not None or stream.held is not None:
        return False
    for s in stream.sessions.values():
        if s.portable is None:
            s.portable = portable(s.tracker)
        if not s.portable:
            return False
    return True


def pack(stream: Stream) -> StreamState:
    """The stream's state, for the worker that adopts it."""
    return StreamState(stream.stream_id, stream.numbering,
                       tuple(SessionState.of(s) for s in stream.sessions.values()))
