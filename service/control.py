"""The control plane: answers ``<prefix>/control`` queries and hands sessions to workers.

It runs in the main process. Its query callback does only cheap work: decode, validate
(``arcf.make_params`` rejects unknown presets and bad overrides up front), choose the owning
worker and enqueue the command. Tracking never happens here.

With several instances on one Zenoh network, every instance receives every request (clients
query with target ALL) and exactly one answers: the owner of the request's stream (see
:mod:`arcf.service.cluster`), or, for a request about nothing known (an unknown session, a status
request, a malformed message), the owner of the request itself. All instances agree on who
that is without talking, so a client may reach the service through any of them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import logging
import secrets
import threading
import time
import uuid
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

from arcf.errors import InvalidParameterError, UnknownPresetError
from arcf.presets import HOST_PARAMETERS, TUNABLE, TrackerParams
from arcf.registry import ALL_PRESETS, available_presets, request_params
from arcf.schemas import (
    Ack,
    ErrorCode,
    ErrorMessage,
    ParameterInfo,
    PresetInfo,
    Presets,
    PresetsRequest,
    ReinitRequest,
    SchemaError,
    SessionInfo,
    SessionSpec,
    StartRequest,
    Status,
    StatusRequest,
    StopRequest,
    decode,
    encode,
    from_json,
    to_json,
)

from .cluster import Cluster, owner
from .commands import (
    AdoptStream,
    Command,
    Fenced,
    PrepareStream,
    ReinitSession,
    ReleaseStream,
    SessionsEnded,
    SessionStat,
    SessionStats,
    StartSession,
    StopSession,
)
from .handoff import StreamState
from .placement import LoadBook, Move
from .settings import ServiceSettings
from .supervision import Strikes

__all__ = ["ControlPlane", "SessionRecord", "owner"]

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger(__name__)

#: What a station asks on the control key, and what it is answered.
Request = StartRequest | ReinitRequest | StopRequest | StatusRequest | PresetsRequest
Reply = Ack | Status | Presets
#: Streams whose id starts so are the start-up's own readiness check (``arcf.service.app``): their
#: session lives for one start and stop on this instance and is never in the cluster's
#: registry (a registry entry could outlive it in another instance's copy, and be "taken
#: over" when this instance dies).
READINESS_PREFIX = "_ready-"


def readiness_stream(instance_id: str) -> str:
    """The stream of an instance's readiness check."""
    return f"{READINESS_PREFIX}{instance_id}-0"


def readiness_instance(stream_id: str) -> str | None:
    """The instance whose readiness check runs on ``stream_id`` (None: a station's stream)."""
    if not stream_id.startswith(READINESS_PREFIX):
        return None
    return stream_id[len(READINESS_PREFIX):].rpartition("-")[0]


@dataclass
class SessionRecord:
    session_id: str
    stream_id: str
    preset: str
    worker: int
    started: float
    client_id: str | None = None
    #: SHA-256 (hex) of the session's control token; None for a session registered without
    #: one (by an instance of an earlier version)
    token_sha256: str | None = None


class ControlPlane:
    def __init__(self, settings: ServiceSettings, worker_queues: Sequence[Any], version: str,
                 responses: Any = None, timeout: float = 10.0,
                 cluster: Cluster | None = None) -> None:
        self.settings = settings
        self.cluster = cluster
        self.queues = worker_queues
        self.responses = responses
        self.timeout = timeout
        self._waiting: dict[str, tuple[threading.Event, list[Any]]] = {}
        if responses is not None:
            self.pump_thread = threading.Thread(target=self._pump, name="arcf-control-pump",
                                                daemon=True)
            self.pump_thread.start()
        self.version = version
        #: preset -> why it cannot run here ("": it can): the Siamese networks' files are
        #: checked once, at start (the workers load them from the same folder)
        self.unavailable = {name: why for name, why in
                            available_presets(settings.models_dir).items()
                            if why}
        for name, why in self.unavailable.items():
            log.warning("preset %s is not available: %s", name, why)
        self.started = time.time()
        self.sessions: dict[str, SessionRecord] = {}
        #: what each worker last reported of its sessions (``status``)
        self.stats: dict[int, dict[str, SessionStat]] = {}
        #: stations whose liveliness token is up (``client_id`` of ``start``)
        self.live_clients: set[str] = set()
        #: stations gone, with sessions here: when those sessions end (monotonic s)
        self.client_deadlines: dict[str, float] = {}
        self.lock = threading.Lock()
        # Work the pump hands off: ending sessions takes ``op_lock``, which a request may hold
        # while it waits on the pump for a worker's confirmation.
        self.background = ThreadPoolExecutor(1, thread_name_prefix="arcf-control-bg")
        # Requests and rebalancing change what runs here; one at a time, or a rebalance could
        # see a session admitted but not yet in the registry and stop it as withdrawn.
        self.op_lock = threading.RLock()
        #: crashes attributed to streams, and the streams quarantined for them
        self.strikes = Strikes(settings.quarantine_after, settings.quarantine_s)
        #: replacement workers not ready yet: sessions go to a live worker meanwhile
        self.starting: set[int] = set()
        #: what each stream costs, from the workers' reports (placement and moves)
        self.book = LoadBook(min_gain=settings.balance_min_gain,
                             busy_above=settings.balance_busy_above)
        #: workers reported since the last balance, and when it was (monotonic)
        self._reported: set[int] = set()
        self._balanced_at = time.monotonic()

    def _pump(self) -> None:
        """Hand workers' confirmations to the requests waiting for them. Never blocks on a
        lock a request may hold (the rest goes to the background thread), never dies."""
        while True:
            try:
                item = self.responses.get()
            except (EOFError, OSError, TypeError, ValueError):  # queue closed at shutdown
                return
            if item is None:
                return
            try:
                self._take(item)
            except Exception:
                log.exception("control: a worker message could not be handled: %r", item)

    def _take(self, item: Any) -> None:
        if isinstance(item, Fenced):
            self._fenced(item.worker, item.sessions)
        elif isinstance(item, SessionsEnded):
            self.background.submit(self._ended, item)
        elif isinstance(item, SessionStats):
            now = time.monotonic()
            with self.lock:
                self.stats[item.worker] = item.sessions
                self.book.report(item.streams)
                self._reported.add(item.worker)
                due = [c for c, t in self.client_deadlines.items() if t <= now]
                for client in due:
                    del self.client_deadlines[client]
                balance = (self.settings.balance_s > 0 and len(self.queues) > 1
                           and now - self._balanced_at >= self.settings.balance_s
                           and self._reported >= set(range(len(self.queues))))
                if balance:
                    self._reported.clear()
                    self._balanced_at = now
            for client in due:
                self.background.submit(self._client_gone, client)
            if balance:
                self.background.submit(self.balance)
        else:
            with self.lock:
                waiter = self._waiting.pop(item.reply_id, None)
            if waiter is not None:
                waiter[1].extend((item.ok, item.message, item.code, item.state))
                waiter[0].set()

    def _forward(self, worker: int, cmd: Command) -> StreamState | None:
        """Send a command to its worker and wait until the worker has applied it; what the
        worker gave back (a released stream's state), if anything."""
        if self.responses is None:
            self.queues[worker].put(cmd)
            return None
        cid = uuid.uuid4().hex
        event, slot = threading.Event(), list[Any]()
        with self.lock:
            self._waiting[cid] = (event, slot)
        self.queues[worker].put(dataclasses.replace(cmd, reply_id=cid))
        if not event.wait(self.timeout):
            with self.lock:
                self._waiting.pop(cid, None)
            if isinstance(cmd, StartSession):  # it may still start: make sure it does not stay
                self.queues[worker].put(StopSession(cmd.session_id))
            raise _Refused(ErrorCode.INTERNAL,
                           f"worker {worker} did not confirm within {self.timeout} s")
        if not slot[0]:
            if slot[2]:  # refused for the request's own fault
                raise _Refused(ErrorCode(slot[2]), slot[1])
            raise _Refused(ErrorCode.INTERNAL, f"worker {worker} failed: {slot[1]}")
        return cast("StreamState | None", slot[3])

    def _ended(self, item: SessionsEnded) -> None:
        """A worker ended sessions by itself (idle, unusable box, over budget): they are gone
        from this instance and from the cluster's registry, so nobody resumes them."""
        with self.op_lock:
            with self.lock:
                for sid in item.sessions:
                    self.sessions.pop(sid, None)
            if self.cluster is not None:
                for sid in item.sessions:
                    self.cluster.withdraw(sid)

    # ------------------------------------------------------------------ stations
    def client_token(self, client_id: str, alive: bool) -> None:
        """A station's liveliness token appeared or vanished. Its sessions here end
        ``client_grace_s`` after it vanished, unless it came back meanwhile (a reconnect
        cancels the deadline). Only stations with sessions here are remembered, and the
        deadlines are checked once a second (with the workers' reports), so token churn
        costs neither threads nor memory."""
        with self.lock:
            if alive:
                self.live_clients.add(client_id)
                self.client_deadlines.pop(client_id, None)
                return
            self.live_clients.discard(client_id)
            if any(r.client_id == client_id for r in self.sessions.values()):
                self.client_deadlines[client_id] = (time.monotonic()
                                                    + self.settings.client_grace_s)

    def _adopt(self, rec: SessionRecord, client_id: str) -> None:
        """A station (a restarted one, under a new liveliness token) takes a session over: its
        lifetime follows the new token from now on, the old one's deadline no longer
        concerns it. A token not seen yet gets the grace to appear."""
        with self.lock:
            rec.client_id = client_id
            if client_id not in self.live_clients:
                self.client_deadlines.setdefault(
                    client_id, time.monotonic() + self.settings.client_grace_s)

    def _client_gone(self, client_id: str) -> None:
        with self.lock:
            if client_id in self.live_clients:
                return
            mine = [r for r in self.sessions.values() if r.client_id == client_id]
        for rec in mine:
            with self.op_lock:
                with self.lock:
                    if self.sessions.pop(rec.session_id, None) is None:
                        continue
                if self.cluster is not None:
                    self.cluster.withdraw(rec.session_id)
                try:
                    self._forward(rec.worker, StopSession(
                        rec.session_id, code=ErrorCode.SESSION_EXPIRED.value,
                        reason=f"session ended: its station ({client_id}) is gone for more "
                               f"than {self.settings.client_grace_s:g} s"))
                except _Refused as exc:
                    log.error("could not end session %s: %s", rec.session_id, exc.message)
            log.info("session %s ended: station %s gone", rec.session_id, client_id)

    def _fenced(self, worker: int, sessions: Sequence[str]) -> None:
        """A worker dropped ``sessions`` because this instance's token was lost (see
        ``Worker._fence``): forget them, and rebalance once the instance is back. Only those:
        a session a rebalance started on the worker meanwhile (a router switch drops and
        restores the token within milliseconds) runs there, and must stay known here, or no
        later rebalance would hand it over (two instances would track its stream)."""
        with self.lock:
            for sid in sessions:
                rec = self.sessions.get(sid)
                if rec is not None and rec.worker == worker:
                    del self.sessions[sid]
        if self.cluster is not None:
            self.cluster.request_rebalance()

    def worker_replaced(self, worker: int, new_queue: Any, culprit: str | None = None
                        ) -> tuple[list[SessionRecord], bool]:
        """A worker died and a new one is starting in its place: its sessions are gone (their
        trackers lived in that process). Forget them and return them, so their streams can
        be told, with whether ``culprit`` (the stream whose frame the worker was processing)
        is now quarantined. Until :meth:`worker_ready`, new and resumed sessions go to the
        live workers."""
        from . import metrics

        quarantined = False
        with self.lock:
            lost = [r for r in self.sessions.values() if r.worker == worker]
            for r in lost:
                del self.sessions[r.session_id]
            self.queues = [*self.queues[:worker], new_queue, *self.queues[worker + 1:]]
            self.starting.add(worker)
            if culprit is not None:
                metrics.CRASH_STRIKES.inc()
                quarantined = self.strikes.strike(culprit)
        if quarantined:
            metrics.QUARANTINES.inc()
            log.error("stream %s quarantined: %d worker crashes on its frames within %g s",
                      culprit, self.strikes.after, self.strikes.window_s)
        return lost, quarantined

    def worker_ready(self, worker: int) -> None:
        """A replacement worker's liveliness token is up: it takes sessions again (those
        waiting for a live worker are taken over now)."""
        with self.lock:
            was_starting = worker in self.starting
            self.starting.discard(worker)
        if was_starting and self.cluster is not None:
            self.cluster.request_rebalance()

    def _any_worker_live(self) -> bool:
        with self.lock:
            return len(self.starting) < len(self.queues)

    def quarantine_reason(self, stream_id: str) -> str | None:
        """Why starts on ``stream_id`` are refused, or None when they are not."""
        left = self.strikes.quarantined(stream_id)
        if not left:
            return None
        return (f"stream {stream_id!r} is quarantined for {left:.0f} s more: worker processes "
                f"died {self.strikes.after} times while processing its frames")

    def tracked_streams(self) -> set[str]:
        """Streams with a session anywhere (on any instance)."""
        with self.lock:
            local = {r.stream_id for r in self.sessions.values()}
        if self.cluster is not None:
            local |= {spec.stream_id for spec in self.cluster.all_specs()}
        return local

    # ------------------------------------------------------------------ ownership
    def _mine(self, key: str) -> bool:
        return self.cluster is None or self.cluster.mine(key)

    def rebalance(self) -> None:
        """Make this instance run exactly the sessions whose streams it owns: take over the
        sessions of an instance that left (resuming from their last published box), hand over
        those a newcomer now owns. Called by the cluster whenever membership or the registry
        changed."""

        if self.cluster is None:
            return
        with self.op_lock:
            self._rebalance()

    def _rebalance(self) -> None:
        from . import metrics

        assert self.cluster is not None
        specs = {spec.session_id: spec for spec in self.cluster.all_specs()}
        with self.lock:
            local = dict(self.sessions)
        for sid, spec in specs.items():
            mine = self.cluster.mine(spec.stream_id)
            if mine and sid not in local and self.quarantine_reason(spec.stream_id):
                self.cluster.withdraw(sid)  # not resumed: its frames crash workers
                log.info("session %s of quarantined stream %s withdrawn", sid, spec.stream_id)
            elif mine and sid not in local and not self._any_worker_live():
                continue  # every worker is starting: taken when one is ready (worker_ready)
            elif mine and sid not in local:
                box, frame_seq, resumed = self.cluster.resume_point(sid)
                try:
                    w = self._admit(sid, spec.stream_id, spec.preset, spec.client_id,
                                    spec.control_token_sha256)
                    self._forward(w, StartSession(
                        session_id=sid, stream_id=spec.stream_id, box=box,
                        preset=spec.preset, overrides=dict(spec.overrides), frame_seq=frame_seq,
                        status="resumed" if resumed else "initialized"))
                except _Refused as exc:
                    with self.lock:
                        self.sessions.pop(sid, None)
                    metrics.ERRORS.labels(kind=exc.code.value).inc()  # seen, not only logged
                    log.error("could not take over session %s: %s", sid, exc.message)
                    continue
                metrics.TAKEOVERS.inc()
                log.info("took over session %s of stream %s (from frame %s)", sid,
                         spec.stream_id, frame_seq)
            elif not mine and sid in local:
                self._drop_local(sid)
                metrics.HANDOVERS.inc()
                log.info("handed over session %s of stream %s", sid, spec.stream_id)
        for sid in set(local) - set(specs):  # withdrawn elsewhere: nothing to run any more
            if not local[sid].stream_id.startswith(READINESS_PREFIX):  # never registered
                self._drop_local(sid)

    def end_readiness_checks(self) -> int:
        """End the start-up's own sessions (streams ``READINESS_PREFIX...``) here, including
        one whose start timed out at the requester but was made: they are in no registry, so
        a stop request about them could be answered by an instance that never knew them.
        Returns how many ended."""
        with self.lock:
            mine = [sid for sid, r in self.sessions.items()
                    if r.stream_id.startswith(READINESS_PREFIX)]
        for sid in mine:
            self._drop_local(sid)
        return len(mine)

    def _drop_local(self, session_id: str) -> None:
        with self.lock:
            rec = self.sessions.pop(session_id, None)
        if rec is not None:
            try:
                self._forward(rec.worker, StopSession(session_id))
            except _Refused as exc:
                log.error("could not stop session %s: %s", session_id, exc.message)

    def _admit(self, sid: str, stream_id: str, preset: str,
               client_id: str | None = None, token_sha256: str | None = None) -> int:
        """Record a local session and choose its worker: the stream's worker if it has one
        (every session of a stream on one worker: the frame is decoded once), else the least
        loaded."""
        with self.lock:
            if sid in self.sessions:
                raise _Refused(ErrorCode.INVALID_REQUEST, f"session {sid!r} already exists")
            if len(self.sessions) >= self.settings.max_sessions:
                raise _Refused(ErrorCode.LIMIT_EXCEEDED, f"this instance already runs "
                               f"{len(self.sessions)} sessions (max_sessions)")
            n = sum(1 for r in self.sessions.values() if r.stream_id == stream_id)
            if n >= self.settings.max_sessions_per_stream:
                raise _Refused(ErrorCode.LIMIT_EXCEEDED, f"stream {stream_id!r} already has {n} "
                               "sessions (max_sessions_per_stream)")
            same = [r.worker for r in self.sessions.values() if r.stream_id == stream_id]
            if same:
                w = same[0]
            else:
                # a replacement still starting would hold the session for seconds: a live
                # worker takes it (the starting ones are chosen last); spare workers take
                # only streams moved to them (balance)
                starting = self.starting if len(self.starting) < len(self.queues) else ()
                spares = range(self.settings.workers, len(self.queues))
                w = self.book.place(stream_id, self._where(), len(self.queues),
                                    {*starting, *spares})
            self.sessions[sid] = SessionRecord(sid, stream_id, preset, w, time.time(),
                                               client_id, token_sha256)
            if client_id is not None and client_id not in self.live_clients:
                # a token named but not seen (yet): it has the grace to appear
                self.client_deadlines.setdefault(
                    client_id, time.monotonic() + self.settings.client_grace_s)
        return w

    def _where(self) -> dict[str, int]:
        """stream -> its worker, from the session records (call with ``lock`` held)."""
        return {r.stream_id: r.worker for r in self.sessions.values()}

    # ------------------------------------------------------------------ moves
    def balance(self) -> Move | None:
        """Move one stream from the busiest worker to a less busy one, if the measured loads
        say it is worth it (:mod:`arcf.service.placement`); the move made, if any."""
        from . import metrics

        with self.op_lock:
            with self.lock:
                move = self.book.plan_move(self._where(), len(self.queues), time.monotonic(),
                                           self.starting,
                                           range(self.settings.workers, len(self.queues)))
            if move is None:
                return None
            try:
                self.move(move.stream_id, move.source, move.target)
            except _Refused as exc:
                log.warning("stream %s not moved from worker %d to %d: %s", move.stream_id,
                            move.source, move.target, exc.message)
                metrics.STREAM_MOVES.labels(outcome="refused").inc()
                with self.lock:
                    self.book.moved(move.stream_id, time.monotonic())  # not tried again at once
                return None
            metrics.STREAM_MOVES.labels(outcome="moved").inc()
            log.info("stream %s moved from worker %d to %d (busiest worker %.2f -> %.2f cores)",
                     move.stream_id, move.source, move.target, move.before, move.after)
            return move

    def move(self, stream_id: str, source: int, target: int) -> None:
        """Move a stream and its sessions from worker ``source`` to ``target``, their state
        with them: the target subscribes first (no frame is lost), the source stops, tracks
        what it already received and hands the state over, the target goes on from there.
        Raises ``_Refused`` when the stream stays where it was (its sessions intact), or
        could not be taken up (its sessions then end, withdrawn from the registry)."""
        with self.op_lock:
            with self.lock:
                sids = [r.session_id for r in self.sessions.values() if r.stream_id == stream_id]
                if not sids or any(self.sessions[s].worker != source for s in sids):
                    raise _Refused(ErrorCode.INVALID_REQUEST,
                                   f"stream {stream_id!r} does not run on worker {source}")
            try:
                self._forward(target, PrepareStream(stream_id))
                state = self._forward(source, ReleaseStream(stream_id))
                if state is None:
                    raise _Refused(ErrorCode.INTERNAL, "the released stream came without state")
            except _Refused:
                self._call_off(target, stream_id)
                raise
            try:
                self._forward(target, AdoptStream(stream_id, state))
            except _Refused as exc:
                log.error("stream %s lost its sessions in a move: %s", stream_id, exc.message)
                self._call_off(target, stream_id)
                with self.lock:
                    for sid in sids:
                        self.sessions.pop(sid, None)
                if self.cluster is not None:
                    for sid in sids:
                        self.cluster.withdraw(sid)
                raise
            with self.lock:
                for sid in sids:
                    if sid in self.sessions:
                        self.sessions[sid].worker = target
                self.book.moved(stream_id, time.monotonic())

    def _call_off(self, worker: int, stream_id: str) -> None:
        try:
            self._forward(worker, AdoptStream(stream_id, None))
        except _Refused as exc:
            log.error("worker %d kept a preparation of stream %s: %s", worker, stream_id,
                      exc.message)

    # ------------------------------------------------------------------ queries
    def handle_query(self, query: zenoh.Query) -> None:
        """Zenoh queryable callback: exactly one reply per query, never an exception."""
        payload = query.payload.to_bytes() if query.payload is not None else b""
        reply = self.handle(payload)
        if reply is not None:  # another instance answers this one
            query.reply(query.key_expr, reply)

    def handle(self, payload: bytes) -> bytes | None:
        """The encoded reply to a request, or None when another instance owns the answer.
        A request written as JSON (a JSON object: its first byte ``{``, which no msgpack
        map starts with) is answered in JSON, for Zenoh's own tools (``z_get``)."""
        from . import metrics

        as_json = payload.lstrip()[:1] == b"{"
        out = to_json if as_json else encode
        try:
            accepted = (StartRequest, ReinitRequest, StopRequest, StatusRequest, PresetsRequest)
            request = cast(Request, from_json(payload, accepted) if as_json
                           else decode(payload, expected=accepted))
        except SchemaError as exc:
            if not self._mine("payload:" + hashlib.blake2b(payload, digest_size=8).hexdigest()):
                return None
            metrics.CONTROL.labels(type="invalid", outcome=exc.code.value).inc()
            metrics.ERRORS.labels(kind=exc.code.value).inc()
            return out(ErrorMessage(code=exc.code.value, message=str(exc),
                                    request_id=exc.request_id, stream_id=exc.stream_id,
                                    session_id=exc.session_id))
        kind = request.type  # the wire name: start, reinit, stop, status_request, ...
        if not self._answers(request):
            return None
        try:
            with self.op_lock:  # serialised with rebalancing (see __init__)
                reply = self._dispatch(request)
        except Exception as exc:  # a fault of ours: still one reply, counted, logged
            if not isinstance(exc, _Refused):
                log.exception("control: %s request failed", kind)
                exc = _Refused(ErrorCode.INTERNAL, f"the service failed on this request "
                               f"({type(exc).__name__}); its log says more")
            metrics.CONTROL.labels(type=kind, outcome=exc.code.value).inc()
            metrics.ERRORS.labels(kind=exc.code.value).inc()
            return out(ErrorMessage(code=exc.code, message=exc.message,
                                    request_id=request.request_id,
                                    stream_id=getattr(request, "stream_id", None),
                                    session_id=getattr(request, "session_id", None)))
        metrics.CONTROL.labels(type=kind, outcome="ok").inc()
        return out(reply)

    def _dispatch(self, request: Request) -> Reply:
        if isinstance(request, StartRequest):
            return self._start(request)
        if isinstance(request, ReinitRequest):
            return self._reinit(request)
        if isinstance(request, StopRequest):
            return self._stop(request)
        if isinstance(request, PresetsRequest):
            return self._presets(request)
        return self._status(request)

    def _presets(self, req: PresetsRequest) -> Presets:
        """The presets and what each override accepts (``arcf.presets.TUNABLE``): what a
        request may set, as :meth:`_start` enforces it, nested ones (``scale_filter.*``,
        ``state.*``) included. Library-only parameters (lists, host paths) are left out: a
        wire override is a scalar."""
        from functools import reduce

        kinds = {bool: "bool", int: "int", float: "float", str: "str"}
        wire = {k: t for k, t in TUNABLE.items()
                if t.kind in kinds and k not in HOST_PARAMETERS}
        refused: ErrorCode | None = None
        refusal: str | None = None
        if req.preset is not None:  # a start's preset and overrides, checked as a start's
            try:
                self._check_preset(req.preset, req.overrides)
            except _Refused as exc:
                refused, refusal = exc.code, str(exc)
        return Presets(
            request_id=req.request_id,
            presets=[PresetInfo(name=p.name, values=({k: reduce(getattr, k.split("."), p)
                                                      for k in wire}
                                                     if isinstance(p, TrackerParams) else {}))
                     for p in ALL_PRESETS.values() if p.name not in self.unavailable],
            parameters=[ParameterInfo(name=k, kind=kinds[t.kind], minimum=t.low,
                                      maximum=t.high,
                                      choices=list(t.choices) if t.choices else None)
                        for k, t in wire.items()],
            refused=refused, refusal=refusal)

    def _answers(self, request: Request) -> bool:
        """Whether this instance answers ``request``. A readiness check is answered by the
        instance it checks, whatever the ownership: instances starting side by side can each
        see a different live set for a moment, and a check served elsewhere would leave a
        session there that nothing ends."""
        checked = readiness_instance(getattr(request, "stream_id", None) or "")
        if checked is not None:
            return checked == self.settings.instance_id
        return self._mine(self._responder_key(request))

    def _responder_key(self, request: Request) -> str:
        """What decides which instance answers: the stream, when the request names one or its
        session is known; else the request itself."""
        stream = getattr(request, "stream_id", None)
        sid = getattr(request, "session_id", None)
        if stream is None and sid is not None:
            if self.cluster is not None:
                spec = self.cluster.spec(sid)
                stream = spec.stream_id if spec is not None else None
            else:
                with self.lock:
                    rec = self.sessions.get(sid)
                stream = rec.stream_id if rec is not None else None
        return stream if stream is not None else "request:" + request.request_id

    def _check_preset(self, preset: str, overrides: Mapping[str, Any]) -> None:
        """What a start's preset and overrides must pass: the library's one check (the name,
        no host path, each override's type and range), and the preset's files here."""
        try:
            name, _ = request_params(preset, overrides)
        except InvalidParameterError as exc:
            raise _Refused(ErrorCode.INVALID_PARAMETER, str(exc)) from exc
        except UnknownPresetError as exc:
            raise _Refused(ErrorCode.UNKNOWN_PRESET, str(exc)) from exc
        if name in self.unavailable:
            raise _Refused(ErrorCode.UNKNOWN_PRESET, f"preset {name!r} is not available on "
                           f"this service: {self.unavailable[name]}")

    def _start(self, req: StartRequest) -> Ack:
        self._check_preset(req.preset, req.overrides)
        quarantined = self.quarantine_reason(req.stream_id)
        if quarantined is not None:
            raise _Refused(ErrorCode.QUARANTINED, quarantined)
        sid = req.session_id or uuid.uuid4().hex
        if self.cluster is not None and self.cluster.spec(sid) is not None:
            raise _Refused(ErrorCode.INVALID_REQUEST, f"session {sid!r} already exists")
        token = secrets.token_urlsafe(24)
        digest = _sha256(token)
        w = self._admit(sid, req.stream_id, req.preset, req.client_id, digest)
        try:
            self._forward(w, StartSession(
                session_id=sid, stream_id=req.stream_id, box=req.box, preset=req.preset,
                overrides=dict(req.overrides), frame_seq=req.frame_seq))
        except _Refused:
            with self.lock:
                self.sessions.pop(sid, None)
            raise
        if self.cluster is not None and not req.stream_id.startswith(READINESS_PREFIX):
            self.cluster.publish(SessionSpec(
                session_id=sid, stream_id=req.stream_id, preset=req.preset,
                overrides=dict(req.overrides), box=req.box, frame_seq=req.frame_seq,
                client_id=req.client_id, control_token_sha256=digest))
        return Ack(request_id=req.request_id, session_id=sid, stream_id=req.stream_id,
                   message=f"session started on worker {w} (subscribed, tracker ready)",
                   control_token=token)

    def _record(self, session_id: str) -> SessionRecord:
        with self.lock:
            rec = self.sessions.get(session_id)
        if rec is None:
            if self.cluster is not None and self.cluster.spec(session_id) is not None:
                raise _Refused(ErrorCode.INTERNAL, f"session {session_id!r} is moving to this "
                               "instance (a takeover in progress); retry")
            raise _Refused(ErrorCode.UNKNOWN_SESSION, f"no session {session_id!r}")
        return rec

    def _authorize(self, rec: SessionRecord, token: str | None, action: str) -> None:
        """Under ``session_control = "owner"``, only the holder of the session's control
        token may stop or re-initialise it (docs/service-design.md#who-may-do-what)."""
        if self.settings.session_control == "open":
            return
        if rec.token_sha256 is None:  # registered by an instance that issued no token
            return
        if token is None or not hmac.compare_digest(_sha256(token), rec.token_sha256):
            raise _Refused(ErrorCode.FORBIDDEN, f"{action} of session {rec.session_id!r} "
                           "needs its control token (the one its start was acknowledged "
                           "with)" if token is None else f"{action} of session "
                           f"{rec.session_id!r}: not its control token")

    def _reinit(self, req: ReinitRequest) -> Ack:
        rec = self._record(req.session_id)
        self._authorize(rec, req.control_token, "reinit")
        self._forward(rec.worker, ReinitSession(rec.session_id, req.box, req.frame_seq))
        update: dict[str, Any] = {"box": req.box, "frame_seq": req.frame_seq}
        if req.client_id is not None and req.client_id != rec.client_id:
            self._adopt(rec, req.client_id)
            update["client_id"] = req.client_id
        if self.cluster is not None and (spec := self.cluster.spec(rec.session_id)) is not None:
            # a takeover before the next result starts from the new box (and station), not
            # the old one
            self.cluster.publish(spec.model_copy(update=update))
        return Ack(request_id=req.request_id, session_id=rec.session_id,
                   stream_id=rec.stream_id, message="re-initialisation queued")

    def _stop(self, req: StopRequest) -> Ack:
        rec = self._record(req.session_id)
        self._authorize(rec, req.control_token, "stop")
        with self.lock:
            self.sessions.pop(rec.session_id, None)
        if self.cluster is not None:
            self.cluster.withdraw(rec.session_id)
        # the last result says it ended, for whoever watches it (not only the requester)
        self._forward(rec.worker, StopSession(rec.session_id, reason="stopped by a station's "
                                              "stop request"))
        return Ack(request_id=req.request_id, session_id=rec.session_id,
                   stream_id=rec.stream_id, message="session stopped")

    def _status(self, req: StatusRequest) -> Status:
        with self.lock:
            records = [(r.session_id, r.stream_id, r.preset, r.client_id)
                       for r in self.sessions.values()]
            stats = {sid: st for per_worker in self.stats.values()
                     for sid, st in per_worker.items()}
        if self.cluster is not None:  # every instance's sessions
            records = [(s.session_id, s.stream_id, s.preset, s.client_id)
                       for s in self.cluster.all_specs()]
        if req.stream_id is not None:
            records = [r for r in records if r[1] == req.stream_id]

        with self.lock:
            for sid in self.sessions:  # started here, not reported by its worker yet
                stats.setdefault(sid, SessionStat(0, None, None, "waiting"))

        def info(sid: str, stream: str, preset: str, client: str | None) -> SessionInfo:
            st = stats.get(sid)  # known for this instance's sessions
            return SessionInfo(
                session_id=sid, stream_id=stream, preset=preset, client_id=client,
                frames=st.frames if st else None, state=st.state if st else None,
                last_seq=st.last_seq if st else None,
                last_result_ts_ns=st.last_result_ts_ns if st else None)

        return Status(
            request_id=req.request_id, instance_id=self.settings.instance_id,
            version=self.version, workers=len(self.queues),
            streams=sorted({r[1] for r in records}),
            sessions=[info(*r) for r in sorted(records)],
            uptime_s=time.time() - self.started,
            instances=self.cluster.live() if self.cluster is not None
            else [self.settings.instance_id],
        )


def _sha256(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class _Refused(Exception):
    """A control request refused with its wire error code."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
