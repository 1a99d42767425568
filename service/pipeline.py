"""A stream's frames on their way to the trackers: parse, admit, decode.

Each queued frame is parsed as a ``frame`` message of its stream (or a Foxglove
``CompressedVideo`` from the stream's video key), admitted by the stream's numbering (a
duplicate, a jump, a restart), and decoded by the encoding table (:mod:`arcf.client.media`):
a picture only where the trackers read it, a video unit by the stream's own decoder. Every
refusal is counted and told on the stream's error key, throttled per code.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from arcf.client.foxglove import parse_compressed_video
from arcf.client.media.encodings import Codec, codec_of, decode_image, video_codec
from arcf.client.media.video import Outcome
from arcf.region import RegionFrame
from arcf.schemas import ErrorCode, ErrorMessage, Frame, SchemaError, decode, encode

from .intake import Verdict
from .settings import ServiceSettings
from .stages import StageClock
from .streams import Picture, Stream, read_region
from .turns import DECODE_TURN_S


def count_extent(metrics: Any, image: np.ndarray | RegionFrame) -> None:
    """Count a picture decoded for tracking by how much of it was decoded."""
    extent = "region" if isinstance(image, RegionFrame) else "whole"
    metrics.FRAMES_DECODED.labels(extent=extent).inc()


def wanted_from(stream: Stream) -> int | None:
    """The first frame any session of the stream wants a picture of, when every one of
    them waits for the frame its box was drawn on (None: some session tracks, or may
    start on any frame)."""
    wanted = None
    for s in stream.sessions.values():
        if s.pending_seq is None or s.tracker is None or s.tracker.initialized:
            return None
        wanted = s.pending_seq if wanted is None else min(wanted, s.pending_seq)
    return wanted




class FramePipeline:
    """The frame path of one worker's streams (``metrics``: :mod:`arcf.service.metrics`)."""

    def __init__(self, settings: ServiceSettings, metrics: Any, clock: StageClock) -> None:
        self.settings = settings
        self.metrics = metrics
        self.clock = clock

    def error(self, stream: Stream, code: ErrorCode, message: str, seq: int | None,
              every_s: float = 1.0, count: bool = True) -> None:
        """Count an error and tell the stream, at most one notice per code and ``every_s``
        seconds (a flood of bad frames must not become a flood of notices; each is counted).
        ``count=False`` for a notice that is no refusal."""
        if count:
            self.metrics.ERRORS.labels(kind=code.value).inc()
        stream.notify(code, message, seq, every_s)

    def reset_decoders(self, streams: Iterable[Stream], why: str, cause: str) -> int:
        """Drop every video decoder of ``streams``: each resumes at its next keyframe, told
        ``why`` (a counted resync, by ``cause``); how many were reset."""
        reset = [st for st in streams if st.decoder is not None]
        for st in reset:
            st.decoder, st.held = None, None
            st.unit_times.clear()
            self.metrics.VIDEO_RESYNCS.labels(cause=cause).inc()
            self.error(st, ErrorCode.DECODE_ERROR, why, None)
        return len(reset)

    def report_intake(self, stream: Stream) -> None:
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

    def take(self, stream: Stream, payload: bytes, received_ns: int,
             source: str = "frame", unit_seq: int | None = None) -> Picture | None:
        """One turn of a stream: its queued frame checked and decoded, the picture for its
        sessions to track (None: nothing to track this turn). A video stream's queued units
        are all decoded first (a P-frame cannot be skipped), and only the newest picture is
        tracked: overload drops tracking work, never decoder state. Decoding that backlog
        takes at most ``DECODE_TURN_S`` of this turn: the rest waits for the stream's next
        turn, after every other stream's (its picture is held)."""
        waited = (time.time_ns() - received_ns) / 1e9
        self.metrics.QUEUE_WAIT.observe(max(waited, 0.0))
        stream.window_wait_s = max(stream.window_wait_s, waited)
        stream.window_turns += 1
        t0, c0 = time.perf_counter(), time.thread_time()
        picture = self.ingest(stream, payload, received_ns, source, unit_seq)
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
            newer = self.ingest(stream, *item)
            if newer is not None:
                if picture is not None and picture.has_pixels:
                    self.metrics.FRAMES_DROPPED.inc()  # decoded, superseded, not tracked
                picture = newer
        # CPU time, as the sessions' tracking is counted: a busy machine's preemptions must
        # not make one stream look costlier than its equals
        stream.window_decode_s += time.thread_time() - c0
        return picture if stream.held is None else None

    def ingest(self, stream: Stream, payload: bytes, received_ns: int, source: str,
                unit_seq: int | None) -> Picture | None:
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
            stream.inbox.carries(video=True)
            return self._decode_unit(stream, frame.seq, frame.capture_ts_ns, received_ns,
                                     codec_of(frame.encoding), frame.payload)
        stream.decoder = None
        stream.inbox.carries(video=False)
        stream.unit_times.clear()
        t0, c0 = time.perf_counter(), time.thread_time()
        image, problem = decode_image(frame, self.settings.max_pixels, read_region(stream))
        decode_s = time.perf_counter() - t0
        c0 = clock.since("decode", c0)
        m.DECODE.observe(decode_s)
        clock.since("metrics", c0)
        if image is not None:
            count_extent(m, image)
            return Picture(frame.seq, frame.capture_ts_ns, received_ns, decode_s, image)
        code, text = problem or (ErrorCode.DECODE_ERROR, f"cannot decode {frame.encoding} frame")
        self.error(stream, code, text, frame.seq)
        return Picture(frame.seq, frame.capture_ts_ns, received_ns, decode_s, None, code, text)

    def _parse(self, stream: Stream, payload: bytes) -> Frame | None:
        """The queued bytes as a checked ``frame`` message of this stream, admitted by its
        numbering; None (reported) if not."""
        try:
            frame = decode(payload, expected=Frame, max_payload=self.settings.max_payload)
        except SchemaError as exc:
            self.error(stream, exc.code, str(exc), None)
            return None
        if frame.stream_id != stream.stream_id:
            self.error(stream, ErrorCode.INVALID_KEY,
                        f"frame says stream {frame.stream_id!r} on {stream.stream_id!r}", frame.seq)
            return None
        return frame if self._admit(stream, frame.seq) else None

    def _ingest_compressed_video(self, stream: Stream, payload: bytes, received_ns: int,
                                 seq: int) -> Picture | None:
        """A CDR foxglove.CompressedVideo from the stream's ``video_key``: numbered on arrival
        (``Inbox.video``), stamped with its own ``timestamp``."""
        c0 = time.thread_time()
        try:
            unit = parse_compressed_video(payload)
        except ValueError as exc:
            self.error(stream, ErrorCode.DECODE_ERROR, str(exc), seq)
            self.clock.since("parse", c0)
            return None
        codec = video_codec(unit.format)
        if codec is None:
            self.error(stream, ErrorCode.DECODE_ERROR, f"CompressedVideo format "
                        f"{unit.format[:40]!r} is not h264 or h265", seq)
        admitted = codec is not None and self._admit(stream, seq)
        self.clock.since("parse", c0)
        if not admitted or codec is None:
            return None
        return self._decode_unit(stream, seq, unit.timestamp_ns, received_ns, codec, unit.data)

    def _admit(self, stream: Stream, seq: int) -> bool:
        """The stream's numbering: a plausible next frame (the skipped numbers counted as
        lost), else refused and reported."""
        if stream.handed_through is not None:
            if seq <= stream.handed_through:  # tracked by the worker it moved from
                return False
            stream.handed_through = None
        last, now = stream.numbering.last, time.monotonic()
        verdict, lost = stream.numbering.admit(seq, now)
        if verdict is Verdict.STALE:
            # duplicate or out of order: tracking it would move the trackers back in time
            self.error(stream, ErrorCode.STALE_FRAME, f"frame {seq} is not after frame "
                        f"{last}; dropped", seq, every_s=1.0)
            return False
        if verdict is Verdict.JUMP:
            gap = stream.numbering.plausible_gap(now)
            why = (f"max_seq_gap {gap}" if gap >= self.settings.max_seq_gap else
                   f"what {self.settings.max_stream_fps:g} frames/s could have sent since, "
                   f"plus {stream.numbering.slack}")
            self.error(stream, ErrorCode.SEQUENCE_JUMP, f"frame {seq} is more than "
                        f"{gap} frames after frame {last} ({why}); dropped (a restarted "
                        f"numbering is followed once {self.settings.resync_frames} frames in a "
                        "row agree)", seq, every_s=1.0)
            return False
        if verdict is Verdict.RESTART:
            self.error(stream, ErrorCode.SEQUENCE_RESTARTED, f"the stream's numbering "
                        f"restarted: frame {seq} follows frame {last}; no frame counted "
                        "as lost", seq, count=False)
            for s in stream.sessions.values():  # their ``dropped`` counts from here
                if s.last_seq is not None:
                    s.last_seq = seq - 1
                # a box drawn on a frame of the old numbering (a camera that restarted since
                # the pilot drew it) would wait for that number for good: it applies here
                if s.pending_box is not None and s.pending_seq is not None \
                        and s.pending_seq > seq:
                    s.pending_seq = seq
        self.metrics.FRAMES_DROPPED.inc(lost)
        return True

    def _decode_unit(self, stream: Stream, seq: int, capture_ts_ns: int, received_ns: int,
                     codec: Codec, data: bytes) -> Picture | None:
        """One access unit through the stream's decoder (made at its first unit, remade if
        the codec changes). A unit that cannot be decoded (no keyframe yet, a gap, damage)
        is an error for the sessions, reported on the stream and counted, and the decoder
        waits for the next keyframe."""
        if stream.decoder is None or stream.decoder.codec != codec.ffmpeg:
            stream.decoder = codec.stream_decoder(self.settings.max_pixels,
                                                  self.settings.video_history)
            stream.unit_times.clear()
        times = stream.unit_times
        times[seq] = (capture_ts_ns, received_ns)
        while len(times) > 2 * self.settings.video_queue:
            del times[next(iter(times))]
        t0, c0 = time.perf_counter(), time.thread_time()
        out = stream.decoder.decode(seq, data, (capture_ts_ns, received_ns),
                                    wanted_from=wanted_from(stream))
        decode_s = time.perf_counter() - t0
        c0 = self.clock.since("decode", c0)
        self.metrics.DECODE.observe(decode_s)
        self.clock.since("metrics", c0)
        if out.outcome is Outcome.FRAME:
            if out.resynced is not None:  # a gap that ended at this keyframe
                self.metrics.VIDEO_RESYNCS.labels(cause=out.resynced).inc()
            seq = out.seq if out.seq is not None else seq
            capture_ts_ns, received_ns = times.pop(seq, (capture_ts_ns, received_ns))
            return Picture(seq, capture_ts_ns, received_ns, decode_s, None, video=out)
        if out.outcome is Outcome.NO_FRAME:
            return None
        times.pop(seq, None)
        if out.outcome is Outcome.RESYNC:
            self.metrics.VIDEO_RESYNCS.labels(cause=out.cause or "corrupt").inc()
        text = f"video unit {seq}: {out.reason}"
        self.error(stream, ErrorCode.DECODE_ERROR, text, seq)
        return Picture(seq, capture_ts_ns, received_ns, decode_s, None,
                        ErrorCode.DECODE_ERROR, text)
