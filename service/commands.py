"""What the control plane and the worker processes say to each other (over multiprocessing
queues, pickled). Internal, not part of the wire contract: typed as the wire messages are, so
that a misspelt field fails where it is written instead of as a KeyError in another process.

Control plane -> worker: :class:`StartSession`, :class:`ReinitSession`, :class:`StopSession`,
and a stream's move (:class:`PrepareStream` to the new worker, :class:`ReleaseStream` to the
old, :class:`AdoptStream` to the new), each with the ``reply_id`` the control plane waits on.
Worker -> control plane:
:class:`Confirmation` of a command; :class:`Fenced` when a worker dropped its sessions
because the instance lost its place in the cluster; :class:`SessionsEnded` when it ended
sessions by itself (idle, unusable box, over budget); :class:`SessionStats` every second.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from .placement import StreamLoad

if TYPE_CHECKING:
    from .handoff import StreamState


@dataclass(frozen=True)
class StartSession:
    """Create a session's tracker; it initialises on frame ``frame_seq`` (or the next frame)."""

    session_id: str
    stream_id: str
    box: tuple[float, float, float, float]
    preset: str
    overrides: dict[str, Any] = field(default_factory=dict)
    frame_seq: int | None = None
    #: The first result's status: a new session, or one resumed after a takeover.
    status: Literal["initialized", "resumed"] = "initialized"
    reply_id: str | None = None


@dataclass(frozen=True)
class ReinitSession:
    """Re-initialise a session on a new box from frame ``frame_seq`` (or the next frame)."""

    session_id: str
    box: tuple[float, float, float, float]
    frame_seq: int | None = None
    reply_id: str | None = None


@dataclass(frozen=True)
class StopSession:
    """Stop a session. With a ``reason``, its last result says so: status ``stopped``,
    ``reason`` as its message and ``code`` if the service ended it (not its station); without
    one (a session moving to another instance), no result."""

    session_id: str
    reason: str | None = None
    code: str | None = None
    reply_id: str | None = None


@dataclass(frozen=True)
class PrepareStream:
    """Subscribe to a stream about to move here (its frames queue, untracked, until
    :class:`AdoptStream`), so that no frame published during the move is lost."""

    stream_id: str
    reply_id: str | None = None


@dataclass(frozen=True)
class ReleaseStream:
    """Hand a stream over: stop receiving it, track the frames already received, and answer
    with its sessions' state (``Confirmation.state``) for the worker that adopts it."""

    stream_id: str
    reply_id: str | None = None


@dataclass(frozen=True)
class AdoptStream:
    """Run a prepared stream's sessions from the state another worker released (``state``);
    None drops the preparation (the release failed)."""

    stream_id: str
    state: StreamState | None
    reply_id: str | None = None


Command = (StartSession | ReinitSession | StopSession | PrepareStream | ReleaseStream
           | AdoptStream)


@dataclass(frozen=True)
class Confirmation:
    """A command applied (``ok``) or refused (``code``, a wire error code, and ``message``
    say why; no code: the worker failed)."""

    reply_id: str
    ok: bool
    message: str = ""
    code: str | None = None
    #: what the command gives back: a released stream's state (carried, like every command,
    #: by the queues between the instance's own processes)
    state: StreamState | None = None


@dataclass(frozen=True)
class Fenced:
    """Worker ``worker`` dropped every session it ran (the instance's token was lost): these
    ``sessions``, and only these (a start the control plane sent meanwhile is applied after
    the fence, and runs)."""

    worker: int
    sessions: tuple[str, ...]


@dataclass(frozen=True)
class SessionsEnded:
    """Worker ``worker`` ended these sessions by itself (each got a last ``stopped`` result
    with the reason): the control plane forgets them."""

    worker: int
    sessions: tuple[str, ...]
    reason: str


@dataclass(frozen=True)
class SessionStat:
    """What ``status`` reports of one session."""

    frames: int
    last_seq: int | None
    last_result_ts_ns: int | None
    state: Literal["waiting", "tracking"]


@dataclass(frozen=True)
class SessionStats:
    """Every session of worker ``worker``, and what each of its streams cost over the last
    second (:mod:`arcf.service.placement`), sent once a second."""

    worker: int
    sessions: dict[str, SessionStat]
    streams: dict[str, StreamLoad] = field(default_factory=dict)

