"""A worker process: owns some streams, decodes each frame once, runs every session's tracker.

Frames arrive in an inbox per stream that keeps the newest ``frame_queue`` frames (older ones
are dropped, so the network is never blocked; the gap shows in the frame numbers and is counted).
Zenoh's callback only copies the payload into the inbox and wakes the loop; decoding and tracking
run on this process's own loop, never inside a callback. Commands (start, reinit, stop) come
from the control plane over a multiprocessing queue, pumped into the same wake-up. An idle worker
sleeps on that wake-up instead of polling, so it costs no CPU; with sessions, at most until the
earliest moment one of them would go stale (its stream silent for ``stale_after_s``), when it
publishes that session's ``stale`` notice.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from typing import Any

import cv2

from arcf import create_tracker, warm_up
from arcf.client.media.images import REGION_DECODING
from arcf.client.transport import LOG_FORMAT
from arcf.schemas import (
    ErrorCode,
    KeySpace,
    LastBox,
    LastBoxes,
    Result,
    encode,
)

from . import handoff
from .commands import (
    AdoptStream,
    Command,
    Confirmation,
    Fenced,
    PrepareStream,
    ReinitSession,
    ReleaseStream,
    SessionsEnded,
    SessionStats,
    StartSession,
    StopSession,
)
from .intake import Inbox, Numbering
from .pipeline import FramePipeline
from .placement import StreamLoad
from .sessions import SessionTable
from .settings import ServiceSettings
from .stages import StageClock
from .streams import Picture, ResultsOut, Session, Stream
from .supervision import InFlight
from .tracking import Tracking
from .turns import TurnBudget

log = logging.getLogger(__name__)

#: a stream's history older than this (seconds) is not asked for when a worker subscribes:
#: a box is drawn on what the pilot sees now, and a station silent for longer has restarted
#: or moved on
HISTORY_MAX_AGE_S = 10.0


class _CommandRefused(Exception):
    """A command the worker refuses for the request's own fault (a wire error code)."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


class Worker:
    def __init__(self, index: int, settings: ServiceSettings, commands: Any, responses: Any,
                 stop: Any, inflight: InFlight | None = None) -> None:
        import zenoh
        import zenoh.ext

        from arcf.client.transport import open_session

        from . import metrics  # after the launcher set PROMETHEUS_MULTIPROC_DIR

        self.index = index
        #: the stream whose frame is being processed, for the launcher to read if this
        #: process dies on it (:mod:`arcf.service.supervision`)
        self.inflight = inflight
        self.settings = settings
        self.commands = commands
        self.responses = responses
        self.stop = stop
        self.metrics = metrics
        self.keys = KeySpace(settings.prefix)
        self.zenoh = zenoh
        self.zenoh_ext = zenoh.ext
        # before the liveliness token: "ready" means no first-frame import or compile stall
        log.info("worker %d: preparing the trackers' compiled kernels (the first start on "
                 "a machine compiles them, about a minute; later starts load them)", index)
        log.info("worker %d: kernels ready in %.1f s", index, warm_up())
        if not REGION_DECODING:
            log.warning("JPEG frames are decoded whole: the _jpegregion module was not built "
                        "(it needs a C compiler and libjpeg-turbo's headers at install)")
        # a peer with listeners of its own is what stations link to directly (worker_listen)
        self.session = open_session("peer" if settings.worker_listen else "client",
                                    listen=settings.worker_listen,
                                    connect=settings.worker_endpoints,
                                    config_file=settings.zenoh_config, lease_ms=settings.lease_ms,
                                    max_message_size=settings.transport_limit)
        self.token_key = self.keys.worker_token(settings.instance_id, str(index))
        self.token = self.session.liveliness().declare_token(self.token_key)
        # Fencing: if this instance's token vanishes (its main process hung past the Zenoh
        # lease, or is gone), the other instances take its streams over; this worker must stop
        # tracking them, or two owners would publish results for the same sessions.
        self.fenced = threading.Event()
        self.instance_watch = self.session.liveliness().declare_subscriber(
            self.keys.instance_token(settings.instance_id), self._on_instance_token)
        self.table = SessionTable()
        #: the sessions' last boxes, put at ``last_box_period_ms`` when one changed
        self.boxes = self.session.declare_publisher(
            self.keys.last_boxes(settings.instance_id, str(index)),
            congestion_control=zenoh.CongestionControl.DROP)
        self.boxes_put: dict[str, int] = {}
        #: a box may have changed since the last put; the next may go at ``boxes_due``
        self.boxes_dirty = False
        self.boxes_due = 0.0
        #: streams about to move here: subscribed, their frames queued until adopted
        self.prepared: dict[str, Stream] = {}
        self.busy = metrics.BUSY.labels(worker=str(index))
        #: CPU per stage of a frame's path (arcf_stage_cpu_seconds_total)
        self.clock = StageClock(metrics.STAGE_CPU)
        self.pipeline = FramePipeline(settings, metrics, self.clock)
        self.budget = TurnBudget(settings.worker_budget)
        self.tracking = Tracking(metrics, self.clock, settings.session_budget_ms / 1e3)
        self.memory = metrics.MEMORY.labels(process=f"worker-{index}")
        self.wake = threading.Event()
        self.pending: deque[Command] = deque()
        #: when ``_check_stale`` must look next (monotonic; inf: no session can go stale)
        self.stale_due = math.inf
        threading.Thread(target=self._pump_commands, daemon=True,
                         name=f"worker-{index}-commands").start()

    def _on_instance_token(self, sample: Any) -> None:
        if sample.kind == self.zenoh.SampleKind.DELETE:
            self.fenced.set()
            self.wake.set()

    def _fence(self) -> None:
        """Drop every session and tell the control plane, which forgets them and lets the
        rebalancing start them again if this instance still owns their streams."""
        self.fenced.clear()
        if not len(self.table):
            return
        log.warning("worker %d: instance token lost; dropping %d sessions", self.index,
                    len(self.table))
        self._final_statuses(
            "the service is shutting down; another instance resumes the session if one is live"
            if self.stop.is_set() else
            "this instance lost its place in the cluster; another instance resumes the session "
            "if one is live")
        dropped = tuple(s.session_id for s in self.table)
        for sid in dropped:
            self._stop(sid)
        self.responses.put(Fenced(self.index, dropped))

    def _final_statuses(self, reason: str) -> None:
        """One last result per session, status ``stopped``, code ``interrupted`` (the session
        stays registered and resumes elsewhere, or here after a restart): a ground station
        learns why its results pause instead of watching them stop."""
        for s in self.table:
            self._publish_stopped(s, reason, ErrorCode.INTERRUPTED)

    def _publish_stopped(self, s: Session, reason: str, code: ErrorCode | None) -> None:
        self._publish_notice(s, "stopped", reason, code)

    def _publish_notice(self, s: Session, status: str, reason: str,
                        code: ErrorCode | None) -> None:
        """A result about no frame (``stopped``, ``stale``): no box, NaN signals, the
        session's last frame (0 before its first), stamped now."""
        now = time.time_ns()
        nan = float("nan")
        try:
            s.publisher.put(encode(Result(
                session_id=s.session_id, stream_id=s.stream_id,
                frame_seq=s.last_seq if s.last_seq is not None else 0, capture_ts_ns=now,
                box=[nan, nan, nan, nan], peak=nan, psr=nan, aberrance=nan,
                aberrance_release=nan, scale=nan, status=status, dropped=0,
                message=reason, code=code, received_ts_ns=now, decode_s=0.0, track_s=0.0,
                published_ts_ns=now)))
        except Exception:  # shutting down: a failed notice must not block the rest
            log.debug("%s notice of %s not sent", status, s.session_id, exc_info=True)

    def _check_stale(self, now: float) -> float:
        """Tell the sessions whose stream delivered no frame for ``stale_after_s`` (a
        ``stale`` result, again every ``stale_after_s`` while it lasts: the session table's
        clock); the monotonic time this must look again (inf: nothing can go stale)."""
        notices, due = self.table.stale(now, self.settings.stale_after_s)
        for n in notices:
            if n.first:
                self.metrics.STALE.inc()
                log.info("worker %d: session %s stale: no frame of %s for %.2f s",
                         self.index, n.session.session_id, n.session.stream_id, n.silent_s)
            self._publish_notice(n.session, "stale", n.why, ErrorCode.NO_FRAMES)
        return due

    def _put_last_boxes(self, now: float) -> None:
        """Every session's last box, when one changed: at most once per
        ``last_box_period_ms``, except that a session's first box goes at once (a new
        session is known elsewhere as soon as it has a box). A full list each time: one lost
        message costs nothing but a period."""
        boxes = {s.session_id: s.last_box for s in self.table if s.last_box is not None}
        seqs = {sid: last[0] for sid, last in boxes.items()}
        if seqs == self.boxes_put:
            self.boxes_dirty = False
            return
        if now < self.boxes_due and seqs.keys() <= self.boxes_put.keys():
            return  # the period's put comes at boxes_due (the loop wakes for it)
        try:
            self.boxes.put(encode(LastBoxes(
                instance_id=self.settings.instance_id, worker=self.index,
                boxes=[LastBox(session_id=sid, frame_seq=seq, box=box)
                       for sid, (seq, box) in boxes.items()])))
        except Exception:  # a bug of ours must not stop the loop: the next change retries
            log.exception("worker %d: last boxes not put", self.index)
            self.metrics.ERRORS.labels(kind=ErrorCode.INTERNAL.value).inc()
        self.boxes_put, self.boxes_dirty = seqs, False
        self.boxes_due = now + self.settings.last_box_period_ms / 1e3

    def _end(self, s: Session, reason: str, code: ErrorCode) -> None:
        """End a session by the service's own decision: its last result says why, the
        control plane forgets it, and the refusal is counted."""
        self._publish_stopped(s, reason, code)
        self._stop(s.session_id)
        self.metrics.ERRORS.labels(kind=code.value).inc()
        self.responses.put(SessionsEnded(self.index, (s.session_id,), reason))
        log.info("worker %d: session %s ended: %s", self.index, s.session_id, reason)

    def _release_memory(self, rss: int) -> None:
        """Over ``worker_max_rss_mb``: every video decoder is dropped (each stream resumes at
        its next keyframe, told why) and glibc returns its free memory to the system. A
        decoder holds its reference pictures and FFmpeg's per-unit state; nothing else in a
        worker grows with what a station sends."""
        reset = self.pipeline.reset_decoders(
            self.table.streams.values(), f"the video decoder was reset: the worker's memory "
            f"({rss >> 20} MB) passed worker_max_rss_mb ({self.settings.worker_max_rss_mb}); "
            "waiting for a keyframe", cause="memory")
        released = _trim_heap()
        log.warning("worker %d: %d MB resident, over worker_max_rss_mb: %d video decoder(s) "
                    "reset%s", self.index, rss >> 20, reset,
                    ", free memory returned" if released else "")

    def _shed(self, busy: float, window_s: float) -> None:
        """The per-worker budget, once a second with the window's busy share: the sessions
        whose turns starve the other streams end, saying why (:mod:`arcf.service.turns`)."""
        for shed in self.budget.window(self.table.streams.values(), busy, window_s):
            self.metrics.SHED.labels(cause=shed.cause).inc()
            self._end(shed.session, shed.why, ErrorCode.LIMIT_EXCEEDED)

    def _housekeeping(self, window_s: float) -> None:
        """Once a second: end the sessions idle past ``session_idle_s``, report the rest and
        what each stream cost over the window (``window_s`` seconds)."""
        for s, why in self.table.expired(time.monotonic(), self.settings.session_idle_s):
            self._end(s, why, ErrorCode.SESSION_EXPIRED)
        loads = {}
        for stream in self.table.streams.values():
            loads[stream.stream_id] = StreamLoad(stream.load_cpu_s / max(window_s, 1e-3),
                                                 handoff.movable(stream))
            stream.load_cpu_s = 0.0
        self.responses.put(SessionStats(self.index, self.table.stats(), loads))

    def _drain(self) -> None:
        """On shutdown: finish the frames already received (at most ``frame_queue`` per
        stream, so the time is bounded), then send every session's final status."""
        for stream in list(self.table.streams.values()):
            for _ in range(len(stream.inbox.frames)):
                item = stream.inbox.pop()
                if item is None:
                    break
                try:
                    self._process(stream, *item)
                except Exception:
                    log.exception("worker %d: error while draining %s", self.index,
                                  stream.stream_id)
        self._final_statuses("the service is shutting down; the session resumes on another "
                             "instance if one is live, or here when the service starts again "
                             "with its state file")

    def _pump_commands(self) -> None:
        """Move commands from the control plane's queue into the loop's wake-up."""
        while True:
            try:
                cmd = self.commands.get()
            except (EOFError, OSError, TypeError, ValueError):
                # the launcher is gone, or this process is shutting down under the thread
                # (a closed pipe surfaces as a TypeError from multiprocessing)
                return
            self.pending.append(cmd)
            self.wake.set()

    # ------------------------------------------------------------------ commands
    def _apply(self, cmd: Command) -> None:
        """Apply one command and confirm it, so the control plane's ack means "in effect"."""
        try:
            state = self._apply_command(cmd)
            reply = Confirmation(cmd.reply_id or "", True, state=state)
        except _CommandRefused as exc:
            reply = Confirmation(cmd.reply_id or "", False, str(exc), exc.code.value)
        except Exception as exc:  # reported to the requester, never fatal to the worker
            log.exception("worker %d: command %s failed", self.index, type(cmd).__name__)
            reply = Confirmation(cmd.reply_id or "", False, f"{type(exc).__name__}: {exc}")
        if cmd.reply_id is not None:
            self.responses.put(reply)

    def _apply_command(self, cmd: Command) -> handoff.StreamState | None:
        """Apply ``cmd``; what it gives back (a released stream's state), if anything."""
        if isinstance(cmd, StartSession):
            self._start(cmd)
        elif isinstance(cmd, ReinitSession):
            s = self.table.get(cmd.session_id)
            if s is None:  # ended by the worker meanwhile (idle, box, budget)
                raise _CommandRefused(ErrorCode.UNKNOWN_SESSION,
                                      f"session {cmd.session_id!r} has ended")
            else:
                self._check_frame_seq(s.stream_id, cmd.frame_seq)
                s.pending_box, s.pending_seq = cmd.box, cmd.frame_seq
                s.pending_status = "reinitialized"
                s.last_activity = time.monotonic()
        elif isinstance(cmd, StopSession):
            s = self.table.get(cmd.session_id)
            if s is not None and cmd.reason:
                self._publish_stopped(s, cmd.reason, ErrorCode(cmd.code) if cmd.code else None)
                if cmd.code:
                    self.metrics.ERRORS.labels(kind=cmd.code).inc()
            self._stop(cmd.session_id)
        elif isinstance(cmd, PrepareStream):
            self._prepare(cmd.stream_id)
        elif isinstance(cmd, ReleaseStream):
            return self._release(cmd.stream_id)
        elif isinstance(cmd, AdoptStream):
            self._adopt(cmd.stream_id, cmd.state)
        else:
            raise TypeError(f"unknown worker command {cmd!r}")
        return None

    def _check_frame_seq(self, stream_id: str, frame_seq: int | None) -> None:
        """Refuse a box for a frame the stream may never send (the session table's rule)."""
        problem = self.table.frame_seq_problem(stream_id, frame_seq, self.settings.max_seq_gap)
        if problem is not None:
            raise _CommandRefused(ErrorCode.INVALID_REQUEST, problem)

    def _start(self, cmd: StartSession) -> None:
        if self.table.get(cmd.session_id) is not None:
            raise _CommandRefused(ErrorCode.INVALID_REQUEST,
                                  f"session {cmd.session_id!r} already runs here")
        stream_id = cmd.stream_id
        if stream_id in self.prepared:  # moving here: refused, so that it is started again
            raise _CommandRefused(ErrorCode.INTERNAL, f"stream {stream_id!r} is moving to "
                                  "this worker; retry")
        stream = self.table.streams.get(stream_id)
        if cmd.status != "resumed":
            self._check_frame_seq(stream_id, cmd.frame_seq)
        if stream is None:
            stream = self._declare_stream(stream_id)
        pub = self._declare_results(stream_id, cmd.session_id)
        try:
            # after every declaration (the stream's subscriber, the session's publisher with
            # Zenoh's writer-side filtering): acked means the first frame and result flow
            self._sync_with_router()
            tracker = create_tracker(cmd.preset, models_dir=self.settings.models_dir,
                                     **cmd.overrides)
        except Exception:
            pub.undeclare()
            if not stream.sessions:
                self._drop_stream(stream)
            raise
        s = Session(cmd.session_id, stream_id, cmd.preset, tracker, pub,
                     pending_box=cmd.box, pending_seq=cmd.frame_seq,
                     pending_status=cmd.status)
        if s.pending_status == "resumed" and s.pending_seq:
            # frames between the last published result and the takeover count as dropped
            s.last_seq = s.pending_seq - 1
        self.table.add(s, stream)
        self.metrics.SESSIONS.inc()
        if self.settings.stale_after_s:  # it may go stale before any other deadline
            self.stale_due = min(self.stale_due, s.fresh_at + self.settings.stale_after_s)

    def _declare_stream(self, stream_id: str) -> Stream:
        """Subscribe to a stream's frames (and video key), with its queue and error key."""
        cfg = self.settings
        video_key = cfg.video_key.replace("{stream}", stream_id) if cfg.video_key else None
        inbox = Inbox(self.keys.frames(stream_id), video_key, cfg.frame_queue, cfg.video_queue,
                      cfg.max_stream_fps, cfg.max_payload, self.wake, self.metrics, self.clock,
                      cfg.max_frame_age_ms / 1e3, history=cfg.video_history)
        sub: Any
        if cfg.video_history:
            # advanced: the stream's recent history comes first where its station keeps it
            # (the SDK's video publishers), so that decoding starts at the keyframe before
            # the picture a box was drawn on; plain publishers' samples arrive as to any
            # subscriber
            sub = self.zenoh_ext.declare_advanced_subscriber(
                self.session, self.keys.frames(stream_id), inbox,
                history=self.zenoh_ext.HistoryConfig(max_samples=cfg.video_history,
                                                     max_age=HISTORY_MAX_AGE_S))
        else:
            sub = self.session.declare_subscriber(self.keys.frames(stream_id), inbox)
        errors = self.session.declare_publisher(
            self.keys.errors(stream_id), congestion_control=self.zenoh.CongestionControl.DROP)
        stream = Stream(stream_id, sub, inbox, errors,
                        Numbering(cfg.max_seq_gap, cfg.resync_frames, rate=cfg.max_stream_fps))
        if video_key:
            stream.video_subscriber = self.session.declare_subscriber(video_key, inbox.video)
        self.metrics.STREAMS.inc()
        return stream

    def _declare_results(self, stream_id: str, session_id: str) -> ResultsOut:
        drop = self.zenoh.CongestionControl.DROP
        return ResultsOut(
            self.session.declare_publisher(self.keys.results(stream_id, session_id),
                                           congestion_control=drop),
            self.session.declare_publisher(self.keys.json_results(stream_id, session_id),
                                           congestion_control=drop))

    # ------------------------------------------------------------------ moves
    def _prepare(self, stream_id: str) -> None:
        """Subscribe to a stream moving here; its frames queue until :meth:`_adopt`."""
        if stream_id in self.table.streams or stream_id in self.prepared:
            raise _CommandRefused(ErrorCode.INVALID_REQUEST,
                                  f"stream {stream_id!r} already runs here")
        self.prepared[stream_id] = self._declare_stream(stream_id)
        self._sync_with_router()

    def _release(self, stream_id: str) -> handoff.StreamState:
        """Stop receiving a stream, track the frames it already sent here, and give its
        sessions' state away (they end here without a last result: they go on elsewhere)."""
        stream = self.table.streams.get(stream_id)
        if stream is None:
            raise _CommandRefused(ErrorCode.UNKNOWN_SESSION,
                                  f"stream {stream_id!r} does not run here")
        if not handoff.movable(stream):
            raise _CommandRefused(ErrorCode.INVALID_REQUEST,
                                  f"stream {stream_id!r} cannot move (video, or a tracker "
                                  "whose state cannot be handed over)")
        # every frame the router sent here before the new worker subscribed must be in the
        # queue before the subscription goes (one sent just before could still be on its
        # way to the callback, and would reach neither worker): the router's answer to this
        # query comes after them on the same link
        self._sync_with_router()
        stream.subscriber.undeclare()
        stream.subscriber = _Undeclared()
        if stream.video_subscriber is not None:
            stream.video_subscriber.undeclare()
            stream.video_subscriber = _Undeclared()
        while (item := stream.inbox.pop()) is not None:
            self._process(stream, *item)
        state = handoff.pack(stream)
        for sid in list(stream.sessions):
            self._stop(sid)
        return state

    def _adopt(self, stream_id: str, state: handoff.StreamState | None) -> None:
        """Run a prepared stream's sessions from the state released elsewhere (None: the move
        was called off, the preparation is dropped)."""
        stream = self.prepared.pop(stream_id, None)
        if state is None:
            if stream is not None:
                self._drop_stream(stream)
            return
        if stream is None:
            raise _CommandRefused(ErrorCode.INVALID_REQUEST,
                                  f"stream {stream_id!r} was not prepared here")
        if not state.sessions:  # all ended on the old worker while it finished its frames
            self._drop_stream(stream)
            return
        stream.numbering = state.numbering
        stream.handed_through = state.numbering.last
        for st in state.sessions:
            s = st.session(stream_id, self._declare_results(stream_id, st.session_id))
            self.table.add(s, stream)
            self.metrics.SESSIONS.inc()
        self._sync_with_router()

    def _sync_with_router(self) -> None:
        """Return once the router has processed this worker's latest declarations.

        A subscriber declaration travels to the router asynchronously, and the control plane's
        ack (over a multiprocessing queue) could overtake it: the client would then publish
        the session's first frame before the router knows where to send it (it would be lost;
        ``tests/service/test_start_order.py`` delays this worker's link to show it). A
        liveliness query is answered by the router after everything this session sent before
        it, so its end proves the declarations arrived: not its first reply, which this
        worker's own session gives at once for its own token, but its end, which is the
        router's final answer (a query that times out ends with an error reply instead). It
        must come: a start the router does not confirm is refused rather than acked. One query
        with the whole budget, so that a slow link (or a stalled machine) delays the ack
        instead of failing it."""
        # well inside the control plane's wait (10 s): a start it gave up on must not start
        replies = list(self.session.liveliness().get(self.token_key, timeout=5.0))
        if any(reply.err is not None for reply in replies):
            raise _CommandRefused(ErrorCode.INTERNAL, "the Zenoh router did not confirm this "
                                  "worker's subscription within 5 s; retry")

    def _stop(self, session_id: str) -> None:
        s, emptied = self.table.remove(session_id)
        if s is None:
            return
        s.publisher.undeclare()
        self.metrics.SESSIONS.dec()
        if emptied is not None:
            self._drop_stream(emptied)

    def _drop_stream(self, stream: Stream) -> None:
        """Undeclare a stream no session tracks any more (or that none could start on)."""
        stream.subscriber.undeclare()
        if stream.video_subscriber is not None:
            stream.video_subscriber.undeclare()
        stream.errors.undeclare()
        self.table.discard_stream(stream)
        self.metrics.STREAMS.dec()

    # ------------------------------------------------------------------ frames
    def _process(self, stream: Stream, payload: bytes, received_ns: int,
                 source: str = "frame", unit_seq: int | None = None) -> None:
        """One turn of a stream: its queued frame through the pipeline, then every session
        of the stream on the picture it gave."""
        picture = self.pipeline.take(stream, payload, received_ns, source, unit_seq)
        if picture is not None:
            self._track(stream, picture)

    def _track(self, stream: Stream, picture: Picture) -> None:
        """Every session of the stream on one picture; the sessions that cannot go on end,
        saying why (:mod:`arcf.service.tracking`)."""
        for end in self.tracking.run(stream, picture):
            self._end(end.session, end.why, end.code)

    # ------------------------------------------------------------------ loop
    def run(self) -> None:
        import os

        parent = os.getppid()
        busy_s, t_window = 0.0, time.monotonic()
        while not self.stop.is_set() and os.getppid() == parent:
            # cleared before draining: anything arriving from now on wakes the next round.
            # Asleep until the next stale deadline at the latest (none without sessions: an
            # idle worker still wakes only twice a second)
            due = min(self.stale_due, self.boxes_due if self.boxes_dirty else math.inf)
            self.wake.wait(timeout=min(0.5, max(due - time.monotonic(), 0.0)))
            self.wake.clear()
            worked = True
            # one frame per stream per round, commands in between: fair shares. The fence, the
            # stop and the once-a-second housekeeping are checked every round, so that a
            # worker that never runs out of frames still does them
            while worked and not self.stop.is_set():
                if self.fenced.is_set():
                    self._fence()
                while self.pending:
                    t0 = time.perf_counter()
                    cmd = self.pending.popleft()
                    self._apply(cmd)
                    if time.perf_counter() - t0 > 0.25:  # it stalls every stream of the worker
                        log.warning("worker %d: command %s took %.0f ms", self.index,
                                    type(cmd).__name__, 1e3 * (time.perf_counter() - t0))
                worked = False
                for stream in list(self.table.streams.values()):
                    self.pipeline.report_intake(stream)
                    item = stream.inbox.pop()
                    if item is None:
                        continue
                    worked = True
                    t0, c0 = time.perf_counter(), time.thread_time()
                    if self.inflight is not None:
                        self.inflight.set(stream.stream_id)
                    try:
                        self._process(stream, *item)
                    except Exception:  # a bug must not take the worker (and its streams) down
                        log.exception("worker %d: unexpected error on stream %s", self.index,
                                      stream.stream_id)
                        self.metrics.ERRORS.labels(kind=ErrorCode.INTERNAL.value).inc()
                    finally:
                        if self.inflight is not None:
                            self.inflight.clear()
                    self.boxes_dirty = True
                    spent = time.perf_counter() - t0
                    busy_s += spent
                    stream.load_cpu_s += time.thread_time() - c0
                    if spent > 0.5:
                        log.warning("worker %d: a frame of stream %s took %.0f ms", self.index,
                                    stream.stream_id, 1e3 * spent)
                now = time.monotonic()
                if self.boxes_dirty:
                    self._put_last_boxes(now)
                if now >= self.stale_due:
                    self.stale_due = self._check_stale(now)
                if now - t_window >= 1.0:
                    self.busy.set(busy_s / (now - t_window))
                    rss = self.metrics.resident_bytes()
                    self.memory.set(rss)
                    if self.settings.worker_max_rss_mb and \
                            rss > self.settings.worker_max_rss_mb << 20:
                        self._release_memory(rss)
                    self._shed(busy_s / (now - t_window), now - t_window)
                    self.clock.flush()
                    self._housekeeping(now - t_window)
                    busy_s, t_window = 0.0, now
        if self.stop.is_set():
            self._drain()

    def close(self) -> None:
        self.clock.flush()  # the last partial second
        self.instance_watch.undeclare()
        for stream in self.prepared.values():
            self._drop_stream(stream)
        for s in self.table:
            self._stop(s.session_id)
        self.boxes.undeclare()
        self.token.undeclare()
        self.session.close()


class _Undeclared:
    """In place of a stream's subscriber once a move undeclared it."""

    def undeclare(self) -> None:
        pass


def _trim_heap() -> bool:
    """glibc's ``malloc_trim(0)``: free heap memory back to the system (the worker keeps freed
    blocks otherwise, ``arcf.warmup.keep_freed_memory``). False where there is no glibc."""
    import ctypes

    try:
        return bool(ctypes.CDLL("libc.so.6").malloc_trim(0))
    except (OSError, AttributeError):
        return False


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this worker when its launcher dies, however it dies.

    A worker outliving a SIGKILLed instance would go on tracking its streams next to the
    instance that takes them over (two owners, duplicate results). The run loop also checks the
    parent pid, for systems without ``prctl``."""
    import ctypes
    import signal
    import sys

    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except OSError:
            log.debug("prctl unavailable", exc_info=True)


def worker_main(index: int, settings: ServiceSettings, commands: Any, responses: Any, stop: Any,
                inflight: InFlight | None = None) -> None:
    """Entry point of a spawned worker process."""
    import signal

    _die_with_parent()
    # a spawned process starts with logging unset: without this its sessions' ends (why the
    # service stopped tracking something) would never reach the service's log
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher decides when workers stop
    cv2.setNumThreads(1)
    worker = Worker(index, settings, commands, responses, stop, inflight)
    try:
        worker.run()
    finally:
        worker.close()
