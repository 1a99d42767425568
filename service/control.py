"""The control plane: answers ``<prefix>/control`` queries and hands sessions to workers.

It runs in the main process. Its query callback does only cheap work: decode, validate
(``arcf.make_params`` rejects unknown presets and bad overrides up front), choose the owning
worker and enqueue the command. Tracking never happens here.
"""

from __future__ import annotations

import hashlib
import threading
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from arcf import ARCFError, make_params
from arcf.presets import PRESETS


def owner(stream_id: str, workers: Sequence[int]) -> int:
    """Rendezvous (highest-random-weight) hashing: the worker that owns a stream.

    Every process computes the same owner from the same worker set, and removing or adding a
    worker moves only the streams it owned (the scale-out issue reuses this across instances).
    """
    return max(workers, key=lambda w: _weight(stream_id, w))


def place(stream_id: str, streams_per_worker: Sequence[int]) -> int:
    """The worker for a new stream within one instance: the least-loaded one (fewest streams),
    ties broken by rendezvous rank so the choice is deterministic.

    Pure hashing would put two of two streams on the same worker half the time (measured in
    the load test); counting streams spreads them. Across instances (scale-out) ownership stays
    with :func:`owner`, which needs no shared state.
    """
    workers = range(len(streams_per_worker))
    rank = {w: i for i, w in enumerate(sorted(workers, key=lambda w: -_weight(stream_id, w)))}
    return min(workers, key=lambda w: (streams_per_worker[w], rank[w]))


def _weight(stream_id: str, w: int) -> int:
    return int.from_bytes(hashlib.blake2b(f"{stream_id}\x00{w}".encode(), digest_size=8).digest(),
                          "big")


@dataclass
class SessionRecord:
    session_id: str
    stream_id: str
    preset: str
    worker: int
    started: float


class ControlPlane:
    def __init__(self, settings: Any, worker_queues: Sequence[Any], version: str,
                 responses: Any = None, timeout: float = 10.0) -> None:
        self.settings = settings
        self.queues = worker_queues
        self.responses = responses
        self.timeout = timeout
        self._waiting: dict[str, tuple[threading.Event, list[Any]]] = {}
        if responses is not None:
            threading.Thread(target=self._pump, name="arcf-control-pump", daemon=True).start()
        self.version = version
        self.started = time.time()
        self.sessions: dict[str, SessionRecord] = {}
        self.lock = threading.Lock()

    def _pump(self) -> None:
        """Hand workers' confirmations to the requests waiting for them."""
        while True:
            try:
                item = self.responses.get()
            except (EOFError, OSError, ValueError):  # queue closed at shutdown
                return
            if item is None:
                return
            cid, ok, message = item
            with self.lock:
                waiter = self._waiting.pop(cid, None)
            if waiter is not None:
                waiter[1].extend((ok, message))
                waiter[0].set()

    def _forward(self, worker: int, cmd: dict[str, Any]) -> None:
        """Send a command to its worker and wait until the worker has applied it."""
        if self.responses is None:
            self.queues[worker].put(cmd)
            return
        cid = uuid.uuid4().hex
        event, slot = threading.Event(), []
        with self.lock:
            self._waiting[cid] = (event, slot)
        self.queues[worker].put({**cmd, "id": cid})
        if not event.wait(self.timeout):
            with self.lock:
                self._waiting.pop(cid, None)
            raise _Refused("internal", f"worker {worker} did not confirm within {self.timeout} s")
        if not slot[0]:
            raise _Refused("internal", f"worker {worker} failed: {slot[1]}")

    def worker_replaced(self, worker: int, new_queue: Any) -> list[SessionRecord]:
        """A worker died and a new one took its place: its sessions are gone (their trackers
        lived in that process). Forget them and return them so their streams can be told."""
        with self.lock:
            lost = [r for r in self.sessions.values() if r.worker == worker]
            for r in lost:
                del self.sessions[r.session_id]
            self.queues = [*self.queues[:worker], new_queue, *self.queues[worker + 1:]]
        return lost

    def tracked_streams(self) -> set[str]:
        with self.lock:
            return {r.stream_id for r in self.sessions.values()}

    # ------------------------------------------------------------------ queries
    def handle_query(self, query: Any) -> None:
        """Zenoh queryable callback: exactly one reply per query, never an exception."""
        payload = query.payload.to_bytes() if query.payload is not None else b""
        reply = self.handle(payload)
        query.reply(query.key_expr, reply)

    def handle(self, payload: bytes) -> bytes:
        from schemas import (
            ErrorMessage,
            ReinitRequest,
            SchemaError,
            StartRequest,
            StatusRequest,
            StopRequest,
            decode,
            encode,
        )

        from . import metrics

        try:
            request = decode(payload, expected=(StartRequest, ReinitRequest, StopRequest,
                                                StatusRequest))
        except SchemaError as exc:
            metrics.CONTROL.labels(type="invalid", outcome=exc.code.value).inc()
            return encode(ErrorMessage(code=exc.code.value, message=str(exc)))
        kind = type(request).__name__
        try:
            if isinstance(request, StartRequest):
                reply = self._start(request)
            elif isinstance(request, ReinitRequest):
                reply = self._reinit(request)
            elif isinstance(request, StopRequest):
                reply = self._stop(request)
            else:
                reply = self._status(request)
        except _Refused as exc:
            metrics.CONTROL.labels(type=kind, outcome=exc.code).inc()
            return encode(ErrorMessage(code=exc.code, message=exc.message,
                                       request_id=request.request_id,
                                       stream_id=getattr(request, "stream_id", None),
                                       session_id=getattr(request, "session_id", None)))
        metrics.CONTROL.labels(type=kind, outcome="ok").inc()
        return encode(reply)

    def _start(self, req: Any) -> Any:
        from schemas import Ack

        if req.preset.lower().replace("_", "-") not in PRESETS:
            raise _Refused("unknown_preset", f"unknown preset {req.preset!r}; choose one of "
                           f"{', '.join(sorted(PRESETS))}")
        try:
            make_params(req.preset, **dict(req.overrides))
        except ARCFError as exc:
            raise _Refused("invalid_parameter", str(exc)) from exc
        sid = req.session_id or uuid.uuid4().hex
        with self.lock:
            if sid in self.sessions:
                raise _Refused("invalid_request", f"session {sid!r} already exists")
            n = sum(1 for r in self.sessions.values() if r.stream_id == req.stream_id)
            if n >= self.settings.max_sessions_per_stream:
                raise _Refused("invalid_request", f"stream {req.stream_id!r} already has {n} "
                               "sessions (max_sessions_per_stream)")
            same = [r.worker for r in self.sessions.values() if r.stream_id == req.stream_id]
            if same:
                w = same[0]  # every session of a stream on one worker: decode once
            else:
                load = [0] * len(self.queues)
                for _stream, worker in {(r.stream_id, r.worker) for r in self.sessions.values()}:
                    load[worker] += 1
                w = place(req.stream_id, load)
            self.sessions[sid] = SessionRecord(sid, req.stream_id, req.preset, w, time.time())
        try:
            self._forward(w, {"op": "start", "session_id": sid, "stream_id": req.stream_id,
                              "box": list(req.box), "preset": req.preset,
                              "overrides": dict(req.overrides), "frame_seq": req.frame_seq})
        except _Refused:
            with self.lock:
                self.sessions.pop(sid, None)
            raise
        return Ack(request_id=req.request_id, session_id=sid, stream_id=req.stream_id,
                   message=f"session started on worker {w} (subscribed, tracker ready)")

    def _record(self, session_id: str) -> SessionRecord:
        with self.lock:
            rec = self.sessions.get(session_id)
        if rec is None:
            raise _Refused("unknown_session", f"no session {session_id!r}")
        return rec

    def _reinit(self, req: Any) -> Any:
        from schemas import Ack

        rec = self._record(req.session_id)
        self._forward(rec.worker, {"op": "reinit", "session_id": rec.session_id,
                                   "box": list(req.box), "frame_seq": req.frame_seq})
        return Ack(request_id=req.request_id, session_id=rec.session_id,
                   stream_id=rec.stream_id, message="re-initialisation queued")

    def _stop(self, req: Any) -> Any:
        from schemas import Ack

        rec = self._record(req.session_id)
        with self.lock:
            self.sessions.pop(rec.session_id, None)
        self._forward(rec.worker, {"op": "stop", "session_id": rec.session_id})
        return Ack(request_id=req.request_id, session_id=rec.session_id,
                   stream_id=rec.stream_id, message="session stopped")

    def _status(self, req: Any) -> Any:
        from schemas import SessionInfo, Status

        with self.lock:
            records = list(self.sessions.values())
        return Status(
            request_id=req.request_id, instance_id=self.settings.instance_id,
            version=self.version, workers=len(self.queues),
            streams=sorted({r.stream_id for r in records}),
            sessions=[SessionInfo(session_id=r.session_id, stream_id=r.stream_id,
                                  preset=r.preset, frames=0) for r in records],
            uptime_s=time.time() - self.started,
        )


class _Refused(Exception):
    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
