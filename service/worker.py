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
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from arcf import ARCFError, create_tracker, warm_up
from arcf.client.foxglove import parse_compressed_video
from arcf.client.media.encodings import Codec, codec_of, decode_image, video_codec
from arcf.client.media.images import REGION_DECODING
from arcf.client.media.video import Decoded, Outcome, StreamDecoder
from arcf.client.transport import LOG_FORMAT
from arcf.region import Region, RegionFrame, cover, whole_frame
from arcf.schemas import (
    ErrorCode,
    ErrorMessage,
    Frame,
    KeySpace,
    Result,
    SchemaError,
    decode,
    encode,
)

from .commands import (
    Command,
    Confirmation,
    Fenced,
    ReinitSession,
    SessionsEnded,
    SessionStat,
    SessionStats,
    StartSession,
    StopSession,
)
from .intake import Inbox, Numbering, Verdict
from .stages import StageClock
from .supervision import InFlight

log = logging.getLogger(__name__)


@dataclass
class _Session:
    session_id: str
    stream_id: str
    preset: str
    tracker: Any
    publisher: Any
    pending_box: tuple[float, float, float, float] | None = None
    pending_seq: int | None = None
    pending_status: str = "initialized"
    last_seq: int | None = None
    frames: int = 0
    #: monotonic time of its start or last result (``session_idle_s`` counts from here)
    last_activity: float = field(default_factory=time.monotonic)
    last_result_ns: int | None = None
    #: mean CPU seconds per tracked frame, exponentially weighted (``session_budget_ms``)
    cost_s: float = 0.0
    tracked: int = 0
    #: CPU seconds of its tracking in the worker's current one-second window (``worker_budget``)
    window_cpu_s: float = 0.0
    #: monotonic time of its start or its last result about a frame: with its stream's last
    #: arrival, what ``stale_after_s`` counts from (a reinit brings no frame: not counted)
    fresh_at: float = field(default_factory=time.monotonic)
    #: monotonic time of its last ``stale`` notice; None while its stream delivers
    stale_noticed: float | None = None

    def stat(self) -> SessionStat:
        return SessionStat(self.frames, self.last_seq, self.last_result_ns,
                           "tracking" if self.tracker.initialized and self.pending_box is None
                           else "waiting")


class _CommandRefused(Exception):
    """A command the worker refuses for the request's own fault (a wire error code)."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


#: The most a video stream's backlog may decode in one turn, seconds: the other streams of the
#: worker wait at most this (plus one unit) for a stream that fell behind.
DECODE_TURN_S = 0.05
#: Over ``worker_budget``, a stream counts as starved when one of its frames waited in its
#: queue longer than this, seconds (a frame period at 10 fps), or its queue dropped one.
STARVED_WAIT_S = 0.1
#: Consecutive one-second windows over budget, with a stream starved, before a session is
#: shed (a burst, e.g. a session's first frames, is not an overload).
OVER_BUDGET_WINDOWS = 2
#: The costliest stream is shed only if it costs this many times a starved stream: among
#: equals (more streams of the same kind than the worker can serve) none is to blame, and
#: each keeps its newest frames, dropping the rest (counted), as before.
UNFAIR = 2.0


@dataclass
class _Picture:
    """What one frame (or video access unit) of a stream gave the trackers: pixels, or why
    there are none (``code``, ``text``)."""

    seq: int
    capture_ts_ns: int
    received_ns: int
    decode_s: float
    #: (H, W, 3) or (H, W) uint8, BGR or grey (a JPEG decoded where the trackers read it: a
    #: ``RegionFrame``); None when the frame gave nothing to track or is a video picture not
    #: converted yet
    image: np.ndarray | RegionFrame | None
    code: ErrorCode | None = None
    text: str | None = None
    #: a decoded video picture, converted to ``image`` only if it is tracked (``pixels``): a
    #: unit decoded to keep the chain and superseded costs its decoding only
    video: Decoded | None = None

    @property
    def has_pixels(self) -> bool:
        return self.image is not None or self.video is not None

    def pixels(self, region: Region | None) -> np.ndarray | RegionFrame | None:
        """The picture's pixels, converting a video picture on first use, where the trackers
        read (``region``; its time counted in ``decode_s``)."""
        if self.image is None and self.video is not None:
            t0 = time.perf_counter()
            self.image, self.video = self.video.pixels(region), None
            self.decode_s += time.perf_counter() - t0
        return self.image


@dataclass
class _Stream:
    stream_id: str
    subscriber: Any
    inbox: Inbox
    errors: Any
    numbering: Numbering
    sessions: dict[str, _Session] = field(default_factory=dict)
    #: when each kind of error notice was last put on the stream's error key
    noticed: dict[ErrorCode, float] = field(default_factory=dict)
    #: frames refused at intake already reported, by code
    reported: dict[ErrorCode, int] = field(default_factory=dict)
    #: the subscriber of the stream's CompressedVideo key (``video_key``), if any
    video_subscriber: Any = None
    #: the stream's video decoder, from its first h264 / h265 unit on
    decoder: StreamDecoder | None = None
    #: (capture, arrival) times of the units in the decoder, by number, until their picture
    #: comes out (bounded: units whose picture never comes are forgotten oldest first)
    unit_times: dict[int, tuple[int, int]] = field(default_factory=dict)
    #: a decoded picture held over while the rest of its backlog waits for the next turn
    held: _Picture | None = None
    #: in the worker's current one-second window (``worker_budget``): CPU seconds spent
    #: decoding and converting its frames, the longest a frame of it waited in its queue,
    #: and its queue's drops before it
    window_decode_s: float = 0.0
    window_wait_s: float = 0.0
    window_turns: int = 0
    trimmed_before: int = 0


def _read_region(stream: _Stream) -> Region | None:
    """Where the stream's trackers read the next frame (None: the whole frame, as for a
    session about to start on it or a track searching for its target)."""
    regions: list[Region | None] = []
    for s in stream.sessions.values():
        if s.pending_box is not None:
            return None
        if s.tracker.initialized:
            regions.append(s.tracker.read_region())
    return cover(regions)


def _count_extent(metrics: Any, image: np.ndarray | RegionFrame) -> None:
    """Count a picture decoded for tracking by how much of it was decoded."""
    extent = "region" if isinstance(image, RegionFrame) else "whole"
    metrics.FRAMES_DECODED.labels(extent=extent).inc()


class Worker:
    def __init__(self, index: int, settings: Any, commands: Any, responses: Any,
                 stop: Any, inflight: InFlight | None = None) -> None:
        import zenoh

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
        # before the liveliness token: "ready" means no first-frame import or compile stall
        log.debug("tracker kernels ready in %.2f s", warm_up())
        if not REGION_DECODING:
            log.warning("JPEG frames are decoded whole: the _jpegregion module was not built "
                        "(it needs a C compiler and libjpeg-turbo's headers at install)")
        self.session = open_session("client", connect=settings.worker_endpoints,
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
        self.streams: dict[str, _Stream] = {}
        self.sessions: dict[str, _Session] = {}
        self.busy = metrics.BUSY.labels(worker=str(index))
        #: CPU per stage of a frame's path (arcf_stage_cpu_seconds_total)
        self.clock = StageClock(metrics.STAGE_CPU)
        self.memory = metrics.MEMORY.labels(process=f"worker-{index}")
        self.wake = threading.Event()
        self.pending: deque[Command] = deque()
        #: when ``_check_stale`` must look next (monotonic; inf: no session can go stale)
        self.stale_due = math.inf
        #: consecutive one-second windows over ``worker_budget`` with a stream starved by the
        #: same costliest stream (``over_stream``)
        self.over_budget = 0
        self.over_stream: str | None = None
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
        if not self.sessions:
            return
        log.warning("worker %d: instance token lost; dropping %d sessions", self.index,
                    len(self.sessions))
        self._final_statuses(
            "the service is shutting down; another instance resumes the session if one is live"
            if self.stop.is_set() else
            "this instance lost its place in the cluster; another instance resumes the session "
            "if one is live")
        for sid in list(self.sessions):
            self._stop(sid)
        self.responses.put(Fenced(self.index))

    def _final_statuses(self, reason: str) -> None:
        """One last result per session, status ``stopped``: a ground station learns that its
        session ended, and why, instead of watching results stop."""
        for s in self.sessions.values():
            self._publish_stopped(s, reason, None)

    def _publish_stopped(self, s: _Session, reason: str, code: ErrorCode | None) -> None:
        self._publish_notice(s, "stopped", reason, code)

    def _publish_notice(self, s: _Session, status: str, reason: str,
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
        ``stale`` result, again every ``stale_after_s`` while it lasts); the monotonic time
        this must look again (inf: nothing can go stale).

        A session's clock runs from the later of its last result about a frame (or its start)
        and its stream's last arrival, so a worker busy with other streams, or a frame taking
        longer than ``stale_after_s`` to track, does not make a stream that delivers look
        stale; frames waiting in the inbox mean the same. Cheap: a few comparisons per
        session, run when the earliest deadline passes, not on a fixed tick."""
        after = self.settings.stale_after_s
        due = math.inf
        if not after:
            return due
        for s in list(self.sessions.values()):
            stream = self.streams.get(s.stream_id)
            if stream is None:
                continue
            if stream.inbox.frames:  # frames are waiting: the loop gets to them this round
                due = min(due, now + after / 10)  # and this looks again soon after
                continue
            since = max(s.fresh_at, stream.inbox.arrived)
            at = since + after if s.stale_noticed is None else max(since, s.stale_noticed) + after
            if now >= at:
                if s.stale_noticed is None:
                    self.metrics.STALE.inc()
                    log.info("worker %d: session %s stale: no frame of %s for %.2f s",
                             self.index, s.session_id, s.stream_id, now - since)
                if s.last_seq is None:
                    why = (f"no frame of stream {s.stream_id!r} for {now - since:.1f} s since "
                           "the session started")
                else:
                    why = (f"no frame of stream {s.stream_id!r} for {now - since:.1f} s: the "
                           f"box of frame {s.last_seq} is not current")
                self._publish_notice(s, "stale", why, ErrorCode.NO_FRAMES)
                s.stale_noticed = now
                at = now + after
            due = min(due, at)
        return due

    def _end(self, s: _Session, reason: str, code: ErrorCode) -> None:
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
        reset = [st for st in self.streams.values() if st.decoder is not None]
        for st in reset:
            st.decoder, st.held = None, None
            st.unit_times.clear()
            self.metrics.VIDEO_RESYNCS.labels(cause="memory").inc()
            self._error(st, ErrorCode.DECODE_ERROR, f"the video decoder was reset: the worker's "
                        f"memory ({rss >> 20} MB) passed worker_max_rss_mb "
                        f"({self.settings.worker_max_rss_mb}); waiting for a keyframe", None)
        released = _trim_heap()
        log.warning("worker %d: %d MB resident, over worker_max_rss_mb: %d video decoder(s) "
                    "reset%s", self.index, rss >> 20, len(reset),
                    ", free memory returned" if released else "")

    def _shed(self, busy: float, window_s: float) -> None:
        """The per-worker budget: once a second, with the window's busy share. A worker busier
        than ``worker_budget`` while a stream's frames wait (or are dropped) for
        ``OVER_BUDGET_WINDOWS`` windows sheds its costliest stream (:meth:`_shed_stream`).
        Costliest by what a turn of the stream costs (the wait it puts on every other
        stream), and only if that is ``UNFAIR`` times a starved stream's turn; a starved
        stream that is itself the costliest is only behind its own work: nothing is shed for
        it."""
        streams = list(self.streams.values())
        starved = set()
        for st in streams:
            trimmed = st.inbox.trimmed
            if st.window_wait_s > STARVED_WAIT_S or trimmed > st.trimmed_before:
                starved.add(st.stream_id)
            st.trimmed_before, st.window_wait_s = trimmed, 0.0
        # what one turn of each stream costs the others: its decoding and its sessions'
        # tracking, per frame it was served
        turn = {st.stream_id: (st.window_decode_s + sum(x.window_cpu_s
                                                        for x in st.sessions.values()))
                / max(st.window_turns, 1) for st in streams}
        budget = self.settings.worker_budget
        heaviest = max(turn, key=turn.__getitem__, default=None)
        victims = [turn[sid] for sid in starved if sid != heaviest]
        if (budget and busy > budget and heaviest is not None and victims
                and turn[heaviest] > UNFAIR * min(victims)):
            # the same stream to blame window after window: one window's noise (a frame
            # that cost more, a preemption) never sheds anything
            same = heaviest == self.over_stream
            self.over_budget = self.over_budget + 1 if same else 1
            self.over_stream = heaviest
        else:
            self.over_budget, self.over_stream = 0, None
        if self.over_budget >= OVER_BUDGET_WINDOWS and heaviest is not None:
            # once shed, one more window over budget sheds again (the load is known to be real)
            self.over_budget = OVER_BUDGET_WINDOWS - 1
            self._shed_stream(self.streams[heaviest], UNFAIR * min(victims), busy, window_s)
        for st in streams:
            st.window_decode_s, st.window_turns = 0.0, 0
        for x in self.sessions.values():
            x.window_cpu_s = 0.0

    def _shed_stream(self, stream: _Stream, fair_turn_s: float, busy: float,
                     window_s: float) -> None:
        """End what makes ``stream``'s turn cost more than ``fair_turn_s``: every session when
        decoding it costs more than any one session's tracking; else its sessions, costliest
        first, until what is left of its turn fits (so a stream of twelve heavy sessions is
        brought down in one go, not one a window)."""
        turns = max(stream.window_turns, 1)
        sessions = sorted(stream.sessions.values(), key=lambda x: x.window_cpu_s, reverse=True)
        share = (f"the most on a worker {100 * busy:.0f} % busy, over worker_budget "
                 f"{100 * self.settings.worker_budget:g} %, while other streams waited")
        if stream.window_decode_s > sessions[0].window_cpu_s:
            why = (f"session ended: decoding stream {stream.stream_id!r} took "
                   f"{1e3 * stream.window_decode_s / window_s:.0f} ms of CPU a second "
                   f"({1e3 * stream.window_decode_s / turns:.0f} ms a turn), {share}")
            self.metrics.SHED.labels(cause="decoding").inc(len(sessions))
            for s in sessions:
                self._end(s, why, ErrorCode.LIMIT_EXCEEDED)
            return
        turn_s = (stream.window_decode_s + sum(s.window_cpu_s for s in sessions)) / turns
        for s in sessions:
            if turn_s <= fair_turn_s:
                break
            turn_s -= s.window_cpu_s / turns
            self.metrics.SHED.labels(cause="tracking").inc()
            self._end(s, f"session ended: its tracking took {1e3 * s.window_cpu_s / window_s:.0f}"
                      f" ms of CPU a second, on stream {stream.stream_id!r}, {share}",
                      ErrorCode.LIMIT_EXCEEDED)

    def _housekeeping(self) -> None:
        """Once a second: end the sessions idle past ``session_idle_s``, report the rest."""
        now = time.monotonic()
        idle = self.settings.session_idle_s
        for s in list(self.sessions.values()):
            if now - s.last_activity <= idle:
                continue
            if s.tracker.initialized and s.pending_box is None:
                why = f"no frame of stream {s.stream_id!r} for {idle:g} s"
            else:
                after = "the next frame" if s.pending_seq is None else f"frame {s.pending_seq}"
                why = f"waited {idle:g} s for {after} of stream {s.stream_id!r}"
            self._end(s, f"session ended: {why}", ErrorCode.SESSION_EXPIRED)
        self.responses.put(SessionStats(
            self.index, {sid: s.stat() for sid, s in self.sessions.items()}))

    def _drain(self) -> None:
        """On shutdown: finish the frames already received (at most ``frame_queue`` per
        stream, so the time is bounded), then send every session's final status."""
        for stream in list(self.streams.values()):
            for _ in range(len(stream.inbox.frames)):
                item = stream.inbox.pop()
                if item is None:
                    break
                try:
                    self._process(stream, *item)
                except Exception:
                    log.exception("worker %d: error while draining %s", self.index,
                                  stream.stream_id)
        self._final_statuses("the service is shutting down")

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
            self._apply_command(cmd)
            reply = Confirmation(cmd.reply_id or "", True)
        except _CommandRefused as exc:
            reply = Confirmation(cmd.reply_id or "", False, str(exc), exc.code.value)
        except Exception as exc:  # reported to the requester, never fatal to the worker
            log.exception("worker %d: command %s failed", self.index, type(cmd).__name__)
            reply = Confirmation(cmd.reply_id or "", False, f"{type(exc).__name__}: {exc}")
        if cmd.reply_id is not None:
            self.responses.put(reply)

    def _apply_command(self, cmd: Command) -> None:
        if isinstance(cmd, StartSession):
            self._start(cmd)
        elif isinstance(cmd, ReinitSession):
            s = self.sessions.get(cmd.session_id)
            if s is None:  # ended by the worker meanwhile (idle, box, budget)
                raise _CommandRefused(ErrorCode.UNKNOWN_SESSION,
                                      f"session {cmd.session_id!r} has ended")
            else:
                self._check_frame_seq(self.streams[s.stream_id], cmd.frame_seq)
                s.pending_box, s.pending_seq = cmd.box, cmd.frame_seq
                s.pending_status = "reinitialized"
                s.last_activity = time.monotonic()
        elif isinstance(cmd, StopSession):
            s = self.sessions.get(cmd.session_id)
            if s is not None and cmd.reason:
                self._publish_stopped(s, cmd.reason, ErrorCode(cmd.code) if cmd.code else None)
                if cmd.code:
                    self.metrics.ERRORS.labels(kind=cmd.code).inc()
            self._stop(cmd.session_id)
        else:
            raise TypeError(f"unknown worker command {cmd!r}")

    def _check_frame_seq(self, stream: _Stream | None, frame_seq: int | None) -> None:
        """A box for a frame far beyond the stream's last one would wait for a frame that may
        never come: refused (a box for a past frame applies to the next frame, and its result
        says so)."""
        last = stream.numbering.last if stream is not None else None
        if frame_seq is not None and last is not None and \
                frame_seq > last + self.settings.max_seq_gap:
            raise _CommandRefused(ErrorCode.INVALID_REQUEST, f"frame_seq {frame_seq} is more "
                                  f"than {self.settings.max_seq_gap} frames after the stream's "
                                  f"last frame {last}")

    def _start(self, cmd: StartSession) -> None:
        if cmd.session_id in self.sessions:
            raise _CommandRefused(ErrorCode.INVALID_REQUEST,
                                  f"session {cmd.session_id!r} already runs here")
        stream_id = cmd.stream_id
        stream = self.streams.get(stream_id)
        if cmd.status != "resumed":
            self._check_frame_seq(stream, cmd.frame_seq)
        if stream is None:
            s = self.settings
            video_key = s.video_key.replace("{stream}", stream_id) if s.video_key else None
            inbox = Inbox(self.keys.frames(stream_id), video_key, s.frame_queue, s.video_queue,
                           s.max_stream_fps, s.max_payload, self.wake, self.metrics, self.clock)
            sub = self.session.declare_subscriber(self.keys.frames(stream_id), inbox)
            errors = self.session.declare_publisher(
                self.keys.errors(stream_id), congestion_control=self.zenoh.CongestionControl.DROP)
            stream = self.streams[stream_id] = _Stream(
                stream_id, sub, inbox, errors,
                Numbering(s.max_seq_gap, s.resync_frames, rate=s.max_stream_fps))
            if video_key:
                stream.video_subscriber = self.session.declare_subscriber(video_key, inbox.video)
            self.metrics.STREAMS.inc()
        pub = self.session.declare_publisher(
            self.keys.results(stream_id, cmd.session_id),
            congestion_control=self.zenoh.CongestionControl.DROP)
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
        s = _Session(cmd.session_id, stream_id, cmd.preset, tracker, pub,
                     pending_box=cmd.box, pending_seq=cmd.frame_seq,
                     pending_status=cmd.status)
        if s.pending_status == "resumed" and s.pending_seq:
            # frames between the last published result and the takeover count as dropped
            s.last_seq = s.pending_seq - 1
        stream.sessions[s.session_id] = s
        self.sessions[s.session_id] = s
        self.metrics.SESSIONS.inc()
        if self.settings.stale_after_s:  # it may go stale before any other deadline
            self.stale_due = min(self.stale_due, s.fresh_at + self.settings.stale_after_s)

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
        s = self.sessions.pop(session_id, None)
        if s is None:
            return
        s.publisher.undeclare()
        self.metrics.SESSIONS.dec()
        stream = self.streams[s.stream_id]
        stream.sessions.pop(session_id, None)
        if not stream.sessions:
            self._drop_stream(stream)

    def _drop_stream(self, stream: _Stream) -> None:
        stream.subscriber.undeclare()
        if stream.video_subscriber is not None:
            stream.video_subscriber.undeclare()
        stream.errors.undeclare()
        del self.streams[stream.stream_id]
        self.metrics.STREAMS.dec()

    # ------------------------------------------------------------------ frames
    def _error(self, stream: _Stream, code: ErrorCode, message: str, seq: int | None,
               every_s: float = 1.0, count: bool = True) -> None:
        """Count an error and tell the stream, at most one notice per code and ``every_s``
        seconds (a flood of bad frames must not become a flood of notices; each is counted).
        ``count=False`` for a notice that is no refusal."""
        if count:
            self.metrics.ERRORS.labels(kind=code.value).inc()
        now = time.monotonic()
        if every_s and now - stream.noticed.get(code, -1e9) < every_s:
            return
        stream.noticed[code] = now
        stream.errors.put(encode(ErrorMessage(code=code, message=message,
                                              stream_id=stream.stream_id, frame_seq=seq)))

    def _report_intake(self, stream: _Stream) -> None:
        """Tell a stream about frames its inbox refused (a throttled notice per code; each
        refused frame was counted at intake)."""
        for code, total in list(stream.inbox.refused.items()):  # every round: cheap first
            refused = total - stream.reported.get(code, 0)
            if refused <= 0:
                continue
            now = time.monotonic()
            if now - stream.noticed.get(code, -1e9) < 1.0:
                continue
            why = (f"stream {stream.stream_id!r} exceeds {self.settings.max_stream_fps:g} "
                   "frames/s" if code is ErrorCode.RATE_LIMITED else
                   f"frame messages above max_payload ({self.settings.max_payload} bytes)")
            stream.noticed[code] = now
            stream.reported[code] = total
            stream.errors.put(encode(ErrorMessage(
                code=code, stream_id=stream.stream_id,
                message=f"{why}: {refused} frame(s) refused since the last notice")))

    def _process(self, stream: _Stream, payload: bytes, received_ns: int,
                 source: str = "frame", unit_seq: int | None = None) -> None:
        """Take one queued frame and run the stream's sessions on what it gave. A video
        stream's queued units are all decoded first (a P-frame cannot be skipped), and only
        the newest picture is tracked: overload drops tracking work, never decoder state.
        Decoding that backlog takes at most ``DECODE_TURN_S`` of this turn: the rest waits
        for the stream's next turn, after every other stream's (its picture is held)."""
        waited = (time.time_ns() - received_ns) / 1e9
        self.metrics.QUEUE_WAIT.observe(max(waited, 0.0))
        stream.window_wait_s = max(stream.window_wait_s, waited)
        stream.window_turns += 1
        t0, c0 = time.perf_counter(), time.thread_time()
        picture = self._ingest(stream, payload, received_ns, source, unit_seq)
        if stream.held is not None:
            if picture is None:
                picture = stream.held
            elif stream.held.has_pixels:
                self.metrics.FRAMES_DROPPED.inc()  # decoded, superseded, not tracked
            stream.held = None
        # what is queued now, not what keeps coming: a stream whose units arrive faster than
        # they decode must not hold the loop (its queue overflows instead: a counted resync)
        for _ in range(len(stream.inbox.frames) if stream.decoder is not None else 0):
            if time.perf_counter() - t0 > DECODE_TURN_S:
                stream.held = picture
                break
            item = stream.inbox.pop()
            if item is None:
                break
            newer = self._ingest(stream, *item)
            if newer is not None:
                if picture is not None and picture.has_pixels:
                    self.metrics.FRAMES_DROPPED.inc()  # decoded, superseded, not tracked
                picture = newer
        # CPU time, as the sessions' tracking is counted: a busy machine's preemptions must
        # not make one stream look costlier than its equals
        stream.window_decode_s += time.thread_time() - c0
        if picture is not None and stream.held is None:
            self._track(stream, picture)

    def _ingest(self, stream: _Stream, payload: bytes, received_ns: int, source: str,
                unit_seq: int | None) -> _Picture | None:
        """Check and decode one queued frame: its picture, an error to give the sessions, or
        None (refused before reaching them, or a unit whose picture is not out yet)."""
        if source == "compressed_video":
            return self._ingest_compressed_video(stream, payload, received_ns, unit_seq or 0)
        m, clock = self.metrics, self.clock
        c0 = time.thread_time()
        try:
            frame = self._parse(stream, payload)
        finally:  # a refused frame's checks are parsing too
            clock.since("parse", c0)
        if frame is None:
            return None
        if frame.encoding.is_video:
            stream.inbox.limit = stream.inbox.video_queue
            return self._decode_unit(stream, frame.seq, frame.capture_ts_ns, received_ns,
                                     codec_of(frame.encoding), frame.payload)
        stream.decoder, stream.inbox.limit = None, stream.inbox.image_queue
        stream.unit_times.clear()
        t0, c0 = time.perf_counter(), time.thread_time()
        image, problem = decode_image(frame, self.settings.max_pixels, _read_region(stream))
        decode_s = time.perf_counter() - t0
        c0 = clock.since("decode", c0)
        m.DECODE.observe(decode_s)
        clock.since("metrics", c0)
        if image is not None:
            _count_extent(m, image)
            return _Picture(frame.seq, frame.capture_ts_ns, received_ns, decode_s, image)
        code, text = problem or (ErrorCode.DECODE_ERROR, f"cannot decode {frame.encoding} frame")
        self._error(stream, code, text, frame.seq)
        return _Picture(frame.seq, frame.capture_ts_ns, received_ns, decode_s, None, code, text)

    def _parse(self, stream: _Stream, payload: bytes) -> Frame | None:
        """The queued bytes as a checked ``frame`` message of this stream, admitted by its
        numbering; None (reported) if not."""
        try:
            frame = decode(payload, expected=Frame, max_payload=self.settings.max_payload)
        except SchemaError as exc:
            self._error(stream, exc.code, str(exc), None)
            return None
        if frame.stream_id != stream.stream_id:
            self._error(stream, ErrorCode.INVALID_KEY,
                        f"frame says stream {frame.stream_id!r} on {stream.stream_id!r}", frame.seq)
            return None
        return frame if self._admit(stream, frame.seq) else None

    def _ingest_compressed_video(self, stream: _Stream, payload: bytes, received_ns: int,
                                 seq: int) -> _Picture | None:
        """A CDR foxglove.CompressedVideo from the stream's ``video_key``: numbered on arrival
        (``Inbox.video``), stamped with its own ``timestamp``."""
        c0 = time.thread_time()
        try:
            unit = parse_compressed_video(payload)
        except ValueError as exc:
            self._error(stream, ErrorCode.DECODE_ERROR, str(exc), seq)
            self.clock.since("parse", c0)
            return None
        codec = video_codec(unit.format)
        if codec is None:
            self._error(stream, ErrorCode.DECODE_ERROR, f"CompressedVideo format "
                        f"{unit.format[:40]!r} is not h264 or h265", seq)
        admitted = codec is not None and self._admit(stream, seq)
        self.clock.since("parse", c0)
        if not admitted or codec is None:
            return None
        return self._decode_unit(stream, seq, unit.timestamp_ns, received_ns, codec, unit.data)

    def _admit(self, stream: _Stream, seq: int) -> bool:
        """The stream's numbering: a plausible next frame (the skipped numbers counted as
        lost), else refused and reported."""
        last, now = stream.numbering.last, time.monotonic()
        verdict, lost = stream.numbering.admit(seq, now)
        if verdict is Verdict.STALE:
            # duplicate or out of order: tracking it would move the trackers back in time
            self._error(stream, ErrorCode.STALE_FRAME, f"frame {seq} is not after frame "
                        f"{last}; dropped", seq, every_s=1.0)
            return False
        if verdict is Verdict.JUMP:
            gap = stream.numbering.plausible_gap(now)
            why = (f"max_seq_gap {gap}" if gap >= self.settings.max_seq_gap else
                   f"what {self.settings.max_stream_fps:g} frames/s could have sent since, "
                   f"plus {stream.numbering.slack}")
            self._error(stream, ErrorCode.SEQUENCE_JUMP, f"frame {seq} is more than "
                        f"{gap} frames after frame {last} ({why}); dropped (a restarted "
                        f"numbering is followed once {self.settings.resync_frames} frames in a "
                        "row agree)", seq, every_s=1.0)
            return False
        if verdict is Verdict.RESTART:
            self._error(stream, ErrorCode.SEQUENCE_RESTARTED, f"the stream's numbering "
                        f"restarted: frame {seq} follows frame {last}; no frame counted "
                        "as lost", seq, count=False)
            for s in stream.sessions.values():  # their ``dropped`` counts from here
                if s.last_seq is not None:
                    s.last_seq = seq - 1
        self.metrics.FRAMES_DROPPED.inc(lost)
        return True

    def _decode_unit(self, stream: _Stream, seq: int, capture_ts_ns: int, received_ns: int,
                     codec: Codec, data: bytes) -> _Picture | None:
        """One access unit through the stream's decoder (made at its first unit, remade if
        the codec changes). A unit that cannot be decoded (no keyframe yet, a gap, damage)
        is an error for the sessions, reported on the stream and counted, and the decoder
        waits for the next keyframe."""
        if stream.decoder is None or stream.decoder.codec != codec.ffmpeg:
            stream.decoder = codec.stream_decoder(self.settings.max_pixels)
            stream.unit_times.clear()
        times = stream.unit_times
        times[seq] = (capture_ts_ns, received_ns)
        while len(times) > 2 * self.settings.video_queue:
            del times[next(iter(times))]
        t0, c0 = time.perf_counter(), time.thread_time()
        out = stream.decoder.decode(seq, data)
        decode_s = time.perf_counter() - t0
        c0 = self.clock.since("decode", c0)
        self.metrics.DECODE.observe(decode_s)
        self.clock.since("metrics", c0)
        if out.outcome is Outcome.FRAME:
            if out.resynced is not None:  # a gap that ended at this keyframe
                self.metrics.VIDEO_RESYNCS.labels(cause=out.resynced).inc()
            seq = out.seq if out.seq is not None else seq
            capture_ts_ns, received_ns = times.pop(seq, (capture_ts_ns, received_ns))
            return _Picture(seq, capture_ts_ns, received_ns, decode_s, None, video=out)
        if out.outcome is Outcome.NO_FRAME:
            return None
        times.pop(seq, None)
        if out.outcome is Outcome.RESYNC:
            self.metrics.VIDEO_RESYNCS.labels(cause=out.cause or "corrupt").inc()
        text = f"video unit {seq}: {out.reason}"
        self._error(stream, ErrorCode.DECODE_ERROR, text, seq)
        return _Picture(seq, capture_ts_ns, received_ns, decode_s, None,
                        ErrorCode.DECODE_ERROR, text)

    def _track(self, stream: _Stream, picture: _Picture) -> None:
        """Every session of the stream on one picture (or told why there is none)."""
        m, clock = self.metrics, self.clock
        c0, converts = time.thread_time(), picture.image is None and picture.video is not None
        image = picture.pixels(_read_region(stream) if converts else None)
        stream.window_decode_s += time.thread_time() - c0
        if converts:
            c0 = clock.since("convert", c0)
            if image is not None:
                _count_extent(m, image)
            clock.since("metrics", c0)
        decode_s, received_ns = picture.decode_s, picture.received_ns
        code, text = picture.code, picture.text
        if image is not None:
            m.FRAMES_PROCESSED.inc()
        for s in list(stream.sessions.values()):
            dropped = 0 if s.last_seq is None else max(picture.seq - s.last_seq - 1, 0)
            status, message, r = "tracking", None, None
            error_code: ErrorCode | None = None
            unusable_box = False
            t1, c1 = time.perf_counter(), time.thread_time()
            if image is None:
                status, message = "error", text
                error_code = code
            elif s.pending_box is not None and (
                s.pending_seq is None or picture.seq >= s.pending_seq
            ):
                try:
                    r = s.tracker.init(whole_frame(image), s.pending_box)
                    status = s.pending_status
                    if s.pending_seq is not None and picture.seq > s.pending_seq:
                        message = (f"box of frame {s.pending_seq} applied to frame {picture.seq}"
                                   ", the first this session saw at or after it")
                except ARCFError as exc:
                    status, message = "error", str(exc)
                    error_code, unusable_box = ErrorCode.INVALID_BOX, True
                s.pending_box = None
            elif s.tracker.initialized:
                try:
                    r = s.tracker.update(image)
                except ARCFError as exc:
                    status, message = "error", str(exc)
                    error_code = ErrorCode.INVALID_FRAME
                    m.ERRORS.labels(kind=error_code.value).inc()
            else:
                continue  # waiting for the frame its box was drawn on
            track_s = time.perf_counter() - t1
            cpu_s = time.thread_time() - c1
            clock.add("track", cpu_s)
            c1 += cpu_s
            m.TRACK.observe(track_s)
            c1 = clock.since("metrics", c1)
            s.window_cpu_s += cpu_s
            s.last_seq = picture.seq
            s.frames += 1
            nan = float("nan")
            published = time.time_ns()
            result = Result(
                session_id=s.session_id, stream_id=s.stream_id, frame_seq=picture.seq,
                capture_ts_ns=picture.capture_ts_ns,
                box=list(r.box) if r else [nan, nan, nan, nan],
                peak=r.peak if r else nan, psr=r.psr if r else nan,
                aberrance=r.aberrance if r else nan,
                aberrance_release=r.aberrance_release if r else nan,
                scale=r.scale if r else nan,
                confidence=r.confidence if r else None,
                track_state=r.state.value if r else None,
                reacquired=True if r and r.reacquired else None,
                status=status, dropped=dropped, message=message,
                code=error_code, received_ts_ns=received_ns, decode_s=decode_s,
                track_s=track_s, published_ts_ns=published,
            )
            s.publisher.put(encode(result))
            c1 = clock.since("publish", c1)
            m.RESULTS.inc()
            if picture.capture_ts_ns > 0:
                m.END_TO_END.observe(max(published - picture.capture_ts_ns, 0) / 1e9)
            clock.since("metrics", c1)
            s.last_activity, s.last_result_ns = time.monotonic(), published
            s.fresh_at, s.stale_noticed = s.last_activity, None  # no longer stale
            if unusable_box:  # no tracker to run: the session ends, saying so
                self._end(s, f"session ended: its box does not fit frame {picture.seq} "
                          f"({message})", ErrorCode.INVALID_BOX)
                continue
            if r is None:  # nothing tracked: no cost to weigh (junk cannot dilute the mean)
                continue
            s.tracked += 1
            s.cost_s = cpu_s if s.tracked == 1 else 0.8 * s.cost_s + 0.2 * cpu_s
            budget = self.settings.session_budget_ms / 1e3
            if (s.tracked >= 5 and s.cost_s > budget) or cpu_s > 4 * budget:
                self._end(s, f"session ended: its frames take {1e3 * max(s.cost_s, cpu_s):.0f} "
                          f"ms of CPU, above the {1e3 * budget:g} ms budget of a session "
                          "(session_budget_ms); other streams share its worker",
                          ErrorCode.LIMIT_EXCEEDED)

    # ------------------------------------------------------------------ loop
    def run(self) -> None:
        import os

        parent = os.getppid()
        busy_s, t_window = 0.0, time.monotonic()
        while not self.stop.is_set() and os.getppid() == parent:
            # cleared before draining: anything arriving from now on wakes the next round.
            # Asleep until the next stale deadline at the latest (none without sessions: an
            # idle worker still wakes only twice a second)
            self.wake.wait(timeout=min(0.5, max(self.stale_due - time.monotonic(), 0.0)))
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
                for stream in list(self.streams.values()):
                    self._report_intake(stream)
                    item = stream.inbox.pop()
                    if item is None:
                        continue
                    worked = True
                    t0 = time.perf_counter()
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
                    spent = time.perf_counter() - t0
                    busy_s += spent
                    if spent > 0.5:
                        log.warning("worker %d: a frame of stream %s took %.0f ms", self.index,
                                    stream.stream_id, 1e3 * spent)
                now = time.monotonic()
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
                    busy_s, t_window = 0.0, now
                    self.clock.flush()
                    self._housekeeping()
        if self.stop.is_set():
            self._drain()

    def close(self) -> None:
        self.clock.flush()  # the last partial second
        self.instance_watch.undeclare()
        for sid in list(self.sessions):
            self._stop(sid)
        self.token.undeclare()
        self.session.close()


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


def worker_main(index: int, settings: Any, commands: Any, responses: Any, stop: Any,
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
