"""What a stream's frames must pass before a worker spends anything on them: the inbox that
Zenoh's callback fills (key check, size, the per-stream rate limit, the bounded queue), and the
rules it and the worker apply (:class:`TokenBucket`, the frame :class:`Numbering`). The rules
are pure logic (no Zenoh, no clock of their own), so that each is tested on its own.
"""

from __future__ import annotations

import re
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from arcf.schemas import ErrorCode

from .stages import StageClock


class TokenBucket:
    """``rate`` frames per second, bursts of one second's worth: a station flooding its stream
    is refused the excess at intake, before the frame queue would hide it by dropping."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.capacity = max(rate, 1.0)  # below 1 frame/s, still one frame at a time
        self.tokens = self.capacity
        self.refilled: float | None = None

    def take(self, now: float) -> bool:
        """Whether a frame arriving at ``now`` (monotonic s) is within the rate."""
        if self.refilled is not None:
            self.tokens = min(self.capacity, self.tokens + (now - self.refilled) * self.rate)
        self.refilled = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class Verdict(str, Enum):
    """What a frame's number means for its stream."""

    FIRST = "first"  #: the stream's first frame
    NEXT = "next"  #: after the last one, within ``max_gap`` (the gap: frames lost on the way)
    STALE = "stale"  #: not after the last one (duplicate, reordered): refused
    JUMP = "jump"  #: more than ``max_gap`` ahead: refused, unless confirmed (see RESTART)
    RESTART = "restart"  #: ``confirm`` frames in a row agree on a new numbering: adopted

    @property
    def accepted(self) -> bool:
        return self in (Verdict.FIRST, Verdict.NEXT, Verdict.RESTART)


@dataclass
class Numbering:
    """A stream's frame numbering, which no single frame, and no trickle of frames, can take
    over.

    A frame numbered after the last one is the next frame if its gap is plausible: at most
    ``max_gap``, and at most what ``rate`` frames per second (the stream's rate limit) could
    have sent since the last frame, plus ``slack`` (the frames between were lost on the way and
    are counted as such). Any other number is refused: behind the last one it is stale, beyond
    the plausible gap a jump. A refused frame joins the candidate run it follows (or starts
    one): when a run reaches ``confirm`` frames, the stream follows its numbering, and no frame
    is counted as lost for the switch (a rebooted camera starting at 0, a station resuming
    after an outage). Several runs are kept apart, so frames of another numbering interleaved
    with a station's own cannot keep resetting its run; when there are too many, the one with
    the fewest frames goes. One rogue frame (a wildcard put numbered 10^12, a replayed old
    frame) is refused and forgotten at the stream's next genuine frame.
    """

    max_gap: int
    confirm: int
    rate: float = 60.0
    slack: int = 30
    max_runs: int = 4
    last: int | None = None
    last_time: float = 0.0
    #: candidate runs of refused frames: [their last frame, how many]
    runs: list[list[int]] = field(default_factory=list)

    def plausible_gap(self, now: float) -> int:
        """How far after the last frame a frame arriving at ``now`` may be numbered."""
        return min(self.max_gap, self.slack + int(self.rate * max(now - self.last_time, 0.0)))

    def admit(self, seq: int, now: float) -> tuple[Verdict, int]:
        """The verdict on frame ``seq`` arriving at ``now`` (monotonic s) and how many frames
        it says were lost before it."""
        if self.last is None:
            self.last, self.last_time = seq, now
            return Verdict.FIRST, 0
        if self.last < seq <= self.last + self.plausible_gap(now):
            lost = seq - self.last - 1
            self.last, self.last_time, self.runs = seq, now, []
            return Verdict.NEXT, lost
        for run in self.runs:
            if run[0] < seq <= run[0] + self.max_gap:
                run[0], run[1] = seq, run[1] + 1
                break
        else:
            run = [seq, 1]
            self.runs.append(run)
            if len(self.runs) > self.max_runs:
                self.runs.remove(min(self.runs[:-1], key=lambda r: r[1]))
        if run[1] >= self.confirm:
            self.last, self.last_time, self.runs = seq, now, []
            return Verdict.RESTART, 0
        return (Verdict.STALE if seq <= self.last else Verdict.JUMP), 0


#: how long after a subscription a station's history may arrive (seconds): it comes at once,
#: in the first round trips, but a loaded machine may take seconds to deliver it
HISTORY_WINDOW_S = 10.0

#: a frame message's encoding, as msgpack spells a video one (a 4-byte str), looked for in the
#: first ``_HEAD`` bytes of the message, where the schema's field order puts it before payload
_VIDEO_MARK = re.compile(rb"\xa8encoding\xa4h26[45]")
_HEAD = 256


class Inbox:
    """The newest frames of one stream: filled by Zenoh's callback thread, drained by the loop.

    Intake happens here, before anything is queued: a sample put on any key but the stream's
    own (a wildcard put reaches every stream's subscriber) is refused and counted
    (``invalid_key``), and the stream's rate limit refuses the excess of a flood, counted
    (``rate_limited``) and reported by the loop, instead of the queue silently trimming it.
    ``deque.append``/``popleft`` are atomic, and trimming from the left drops the oldest
    entries, which is the drop-oldest policy a live video stream wants: an image stream keeps
    its newest ``frame_queue`` frames, and of those only the ones that arrived within
    ``max_age_s`` when the loop takes one (unless it is the newest): a burst of work on the
    worker (a session's start, a stream moving in) is absorbed without a drop, while a worker
    that stays behind drops frames instead of falling behind by ``frame_queue`` frame periods
    at a low frame rate; a video stream (h264 / h265 units, or anything on its
    CompressedVideo key) ``video_queue`` units, since each one must reach the decoder.

    Whatever the count, the queue also holds at most ``max_bytes`` (the larger of 32 MiB and
    two frames of ``max_payload``): a station flooding a video stream with huge units cannot
    claim ``video_queue`` times ``max_payload`` of memory.

    Units on the CompressedVideo key carry no number: they are numbered here, as they arrive
    (refused ones included), so that a unit lost to the rate limit or the queue shows as a gap
    to the decoder, which then waits for a keyframe instead of decoding from a broken chain."""

    def __init__(self, key: str, video_key: str | None, image_queue: int, video_queue: int,
                 rate: float, max_payload: int, wake: threading.Event, metrics: Any,
                 clock: StageClock | None = None, max_age_s: float = 0.0,
                 history: int = 0) -> None:
        self.key = key
        self.video_key = video_key
        #: bounded by ``limit`` and ``max_bytes``, trimmed on every append (no ``maxlen``: its
        #: silent drops would escape the byte count)
        self.frames: deque[tuple[bytes, int, str, int | None]] = deque()
        self.image_queue, self.video_queue = image_queue, video_queue
        #: entries kept: ``image_queue`` until the stream turns out to be video (:attr:`is_video`)
        self.limit = image_queue
        #: the stream carries video units (a group of pictures must reach the decoder whole)
        self.is_video = False
        self.video_seq = 0
        #: monotonic time of the last sample queued (never: 0): the stream delivers, so its
        #: sessions are not stale even while the loop is busy elsewhere (written by Zenoh's
        #: thread, read by the loop: a float assignment is atomic)
        self.arrived = 0.0
        self.max_bytes = max(32 << 20, 2 * (max_payload + 1024))
        #: an image stream's frame older than this (ns since its arrival) is dropped when a
        #: newer one waits; 0: off
        self.max_age_ns = int(max_age_s * 1e9)
        self._bytes = 0
        self._lock = threading.Lock()  # the byte count is shared with the loop's pops
        self.bucket = TokenBucket(rate)
        self.max_payload = max_payload
        self.wake = wake
        self.metrics = metrics
        #: the worker's CPU accounting: what a sample costs on Zenoh's thread is "receive"
        self.clock = clock
        #: frames dropped from the queue's old end so far (the stream lagged behind)
        self.trimmed = 0
        #: frames refused here so far, by code (the loop reports them to the stream)
        self.refused: dict[ErrorCode, int] = {ErrorCode.RATE_LIMITED: 0,
                                              ErrorCode.OVERSIZED_PAYLOAD: 0}
        #: a station's recent video, asked for at subscription (up to ``history`` units): it
        #: comes at once, so within ``HISTORY_WINDOW_S`` that many video units pass the rate
        #: limit and get places in the queue beyond ``limit`` (given back as they are taken);
        #: an image stream meets the limit from its first frame
        self.history = history
        self.history_until = time.monotonic() + HISTORY_WINDOW_S
        self.room = history

    def __call__(self, sample: Any) -> None:
        """A sample on the stream's frames key (a ``frame`` message)."""
        self._receive(sample, self.key, "frame")

    def video(self, sample: Any) -> None:
        """A sample on the stream's CompressedVideo key (CDR)."""
        self._receive(sample, self.video_key, "compressed_video")

    def _receive(self, sample: Any, key: str | None, source: str) -> None:
        c0 = time.thread_time()
        try:
            if str(sample.key_expr) != key:
                self.metrics.ERRORS.labels(kind=ErrorCode.INVALID_KEY.value).inc()
            elif source == "frame":
                self._take(sample, source, None)
            else:  # numbered on arrival: a unit lost on the way shows as a gap
                self.carries(video=True)
                seq, self.video_seq = self.video_seq, self.video_seq + 1
                self._take(sample, source, seq)
        finally:
            if self.clock is not None:
                self.clock.since("receive", c0)

    def _take(self, sample: Any, source: str, seq: int | None) -> None:
        self.metrics.FRAMES_RECEIVED.inc()
        # the size first, without copying: an oversized message never takes a place in the
        # queue, nor memory (a frame message is its payload plus a few dozen bytes)
        if len(sample.payload) > self.max_payload + 1024:
            self._refuse(ErrorCode.OVERSIZED_PAYLOAD)
        elif not (self.is_video and self._history_sample()) \
                and not self.bucket.take(time.monotonic()):
            self._refuse(ErrorCode.RATE_LIMITED)
        else:
            data = sample.payload.to_bytes()
            if source == "frame" and not self.is_video and _VIDEO_MARK.search(data, 0, _HEAD):
                # a video unit: the whole group of pictures must be kept from the first one
                # (the loop confirms it when it decodes the message, whatever its field order)
                self.carries(video=True)
            with self._lock:
                self.frames.append((data, time.time_ns(), source, seq))
                self.arrived = time.monotonic()
                self._bytes += len(data)
                room = self.room if self.is_video else 0
                while len(self.frames) > 1 and (len(self.frames) > self.limit + room
                                                or self._bytes > self.max_bytes):
                    # the oldest goes: the gap shows in the numbers, and is counted
                    self._bytes -= len(self.frames.popleft()[0])
                    self.trimmed += 1
            self.wake.set()

    def carries(self, *, video: bool) -> None:
        """What the stream turned out to carry: video units or images (its queue's bound)."""
        self.is_video = video
        self.limit = self.video_queue if video else self.image_queue

    def _history_sample(self) -> bool:
        """Whether a sample counts as the station's history (see ``history``)."""
        if self.history <= 0 or time.monotonic() > self.history_until:
            self.history = 0
            return False
        self.history -= 1
        return True

    def _refuse(self, code: ErrorCode) -> None:
        self.metrics.ERRORS.labels(kind=code.value).inc()
        self.refused[code] += 1
        self.wake.set()

    def pop(self) -> tuple[bytes, int, str, int | None] | None:
        with self._lock:
            if not self.frames:
                return None
            if self.max_age_ns and not self.is_video:
                oldest = time.time_ns() - self.max_age_ns
                while len(self.frames) > 1 and self.frames[0][1] < oldest:
                    # the oldest goes, as when the queue is full: counted, a gap in the numbers
                    self._bytes -= len(self.frames.popleft()[0])
                    self.trimmed += 1
            item = self.frames.popleft()
            self._bytes -= len(item[0])
            if self.room > 0:
                self.room -= 1
            return item
