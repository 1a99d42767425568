"""A stream's sessions on one picture: each tracker's ``init`` or ``update``, its result
published, its cost weighed against the session's budget.

A session's result says what happened to its frame: ``initialized`` / ``reinitialized`` on
the frame its box was drawn on (or the first after it, saying so), ``tracking`` after, and
``error`` with a code when the picture could not be decoded or the tracker refused it. A
session whose box does not fit its frame, or whose frames cost more than
``session_budget_ms``, is returned to the worker to end.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from arcf import ARCFError
from arcf.region import RegionFrame, whole_frame
from arcf.schemas import ErrorCode, Result, encode

from .cluster import usable_box
from .pipeline import count_extent
from .stages import StageClock
from .streams import Picture, Session, Stream, read_region


@dataclass(frozen=True)
class Ending:
    """A session the worker must end: why (its last result's message) and the error code."""

    session: Session
    why: str
    code: ErrorCode


class Tracking:
    """Runs sessions on pictures (``metrics``: :mod:`arcf.service.metrics`)."""

    def __init__(self, metrics: Any, clock: StageClock, session_budget_s: float) -> None:
        self.metrics = metrics
        self.clock = clock
        #: the CPU a session's frame may take on average (``session_budget_ms``)
        self.session_budget_s = session_budget_s

    def run(self, stream: Stream, picture: Picture) -> list[Ending]:
        """Every session of the stream on one picture (or told why there is none), each
        result published on the session's key; the sessions to end, with why."""
        m, clock = self.metrics, self.clock
        ends: list[Ending] = []
        c0, converts = time.thread_time(), picture.image is None and picture.video is not None
        image = picture.pixels(read_region(stream) if converts else None)
        stream.window_decode_s += time.thread_time() - c0
        if converts:
            c0 = clock.since("convert", c0)
            if image is not None:
                count_extent(m, image)
            clock.since("metrics", c0)
        if image is not None:
            m.FRAMES_PROCESSED.inc()
        for s in list(stream.sessions.values()):
            if self._replayable(stream, s, picture):
                ending = self._catch_up(stream, s, picture)
                if ending is not None:
                    ends.append(ending)
                    continue
            ending = self._step(s, picture, image)
            if ending is not None:
                ends.append(ending)
        return ends

    @staticmethod
    def _replayable(stream: Stream, s: Session, picture: Picture) -> bool:
        """Whether a session's box was drawn on a picture before ``picture`` that the
        stream's decoder can decode again (its group of pictures is kept), and that the
        session has not answered yet: a re-drawn track whose results went past it goes on
        from the next picture, so that no frame is answered twice."""
        return (s.pending_box is not None and s.pending_seq is not None
                and s.pending_seq < picture.seq
                and (s.last_seq is None or s.last_seq < s.pending_seq)
                and stream.decoder is not None and stream.decoder.group.covers(s.pending_seq))

    def _catch_up(self, stream: Stream, s: Session, picture: Picture) -> Ending | None:
        """A box drawn on a picture the stream's decoder has passed (the pilot's view lags
        the stream; a fresh subscription's first units are the sender's recent history):
        that picture decoded again from its group's keyframe, the box applied to it, and
        every picture since tracked by this session alone, so that it reaches ``picture``
        on the track the pilot drew. The session's ending, if one of them ends it."""
        assert stream.decoder is not None and s.pending_seq is not None
        pictures = stream.decoder.replay(s.pending_seq, picture.seq - 1)
        while True:
            t0, c0 = time.perf_counter(), time.thread_time()
            item = next(pictures, None)
            if item is None:
                return None
            decoded, tag = item
            region = None if s.pending_box is not None else s.tracker.read_region()
            image = decoded.pixels(region)
            capture_ts_ns, received_ns = tag if tag is not None else (0, 0)
            again = Picture(decoded.seq or 0, capture_ts_ns, received_ns,
                            time.perf_counter() - t0, image)
            stream.window_decode_s += time.thread_time() - c0
            self.clock.since("decode", c0)
            self.metrics.VIDEO_REPLAYED.inc()
            ending = self._step(s, again, image)
            if ending is not None:
                return ending

    def _step(self, s: Session, picture: Picture,
              image: np.ndarray | RegionFrame | None) -> Ending | None:
        """One session on one picture (``image``: its pixels, None if it gave none): its
        tracker's ``init`` or ``update`` and its result published; the session's ending, if
        this frame ends it."""
        m, clock = self.metrics, self.clock
        if (s.pending_seq is not None and picture.seq < s.pending_seq
                and not s.tracker.initialized):
            return None  # before the picture its box was drawn on: not begun yet
        decode_s, received_ns = picture.decode_s, picture.received_ns
        code, text = picture.code, picture.text
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
            return None  # waiting for the frame its box was drawn on
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
        if r is not None and status != "error" and usable_box(r.box):
            s.last_box = (picture.seq, r.box)
        s.last_activity, s.last_result_ns = time.monotonic(), published
        s.fresh_at, s.stale_noticed = s.last_activity, None  # no longer stale
        if unusable_box:  # no tracker to run: the session ends, saying so
            return Ending(s, f"session ended: its box does not fit frame {picture.seq} "
                             f"({message})", ErrorCode.INVALID_BOX)
        if r is None:  # nothing tracked: no cost to weigh (junk cannot dilute the mean)
            return None
        s.tracked += 1
        s.cost_s = cpu_s if s.tracked == 1 else 0.8 * s.cost_s + 0.2 * cpu_s
        budget = self.session_budget_s
        if (s.tracked >= 5 and s.cost_s > budget) or cpu_s > 4 * budget:
            return Ending(s, f"session ended: its frames take "
                                  f"{1e3 * max(s.cost_s, cpu_s):.0f} ms of CPU, above the "
                                  f"{1e3 * budget:g} ms budget of a session "
                                  "(session_budget_ms); other streams share its worker",
                          ErrorCode.LIMIT_EXCEEDED)
        return None
