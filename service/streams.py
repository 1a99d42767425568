"""What a worker keeps per stream and per session, and what one frame gave the trackers.

Plain state, no Zenoh: a stream's ``subscriber``, ``errors`` publisher and a session's
``publisher`` are whatever the worker declared (anything with ``put`` / ``undeclare``), so the
frame pipeline, the session table and the turn scheduler are tested without a network.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from arcf.client.media.video import Decoded, StreamDecoder
from arcf.region import Region, RegionFrame, cover
from arcf.schemas import ErrorCode, ErrorMessage, Result, decode, encode, to_json

from .commands import SessionStat
from .intake import Inbox, Numbering


class ResultsOut:
    """Where a session's results go: msgpack on the contract's key, and the same results as
    JSON on its mirror key (``KeySpace.json_results``) only while a subscriber matches that
    (Zenoh's matching status): a person watching with ``z_sub`` reads them, and nobody pays
    for the second form when nobody watches. ``wire`` and ``mirror`` are declared publishers."""

    def __init__(self, wire: Any, mirror: Any) -> None:
        self.wire, self.mirror = wire, mirror

    def put(self, data: bytes) -> None:
        self.wire.put(data)
        if self.mirror.matching_status.matching:
            self.mirror.put(to_json(decode(data, expected=Result)))

    def undeclare(self) -> None:
        self.wire.undeclare()
        self.mirror.undeclare()


@dataclass
class Session:
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
    #: (frame_seq, box) of its last result with a usable box: what another instance resumes
    #: it from (put on the worker's ``boxes`` key at ``last_box_period_ms``)
    last_box: tuple[int, tuple[float, float, float, float]] | None = None
    #: whether its tracker's state can move to another worker (checked once, when asked:
    #: :func:`arcf.service.handoff.movable`)
    portable: bool | None = None

    def stat(self) -> SessionStat:
        return SessionStat(self.frames, self.last_seq, self.last_result_ns,
                           "tracking" if self.tracker.initialized and self.pending_box is None
                           else "waiting")


@dataclass
class Picture:
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
class Stream:
    stream_id: str
    subscriber: Any
    inbox: Inbox
    errors: Any
    numbering: Numbering
    sessions: dict[str, Session] = field(default_factory=dict)
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
    held: Picture | None = None
    #: in the worker's current one-second window (``worker_budget``): CPU seconds spent
    #: decoding and converting its frames, the longest a frame of it waited in its queue,
    #: and its queue's drops before it
    window_decode_s: float = 0.0
    window_wait_s: float = 0.0
    window_turns: int = 0
    trimmed_before: int = 0
    #: CPU seconds of its turns (decoding and tracking) since the last load report
    #: (:mod:`arcf.service.placement`)
    load_cpu_s: float = 0.0
    #: after a move, the last frame the worker it came from tracked: frames up to it, which
    #: reached both workers during the move, are dropped here without a word
    handed_through: int | None = None

    def notify(self, code: ErrorCode, message: str, seq: int | None = None,
               every_s: float = 1.0) -> bool:
        """Put an error notice on the stream's error key, at most one per code and
        ``every_s`` seconds (a flood of bad frames must not become a flood of notices);
        whether it was sent."""
        now = time.monotonic()
        if every_s and now - self.noticed.get(code, -1e9) < every_s:
            return False
        self.noticed[code] = now
        self.errors.put(encode(ErrorMessage(code=code, message=message,
                                            stream_id=self.stream_id, frame_seq=seq)))
        return True


def read_region(stream: Stream) -> Region | None:
    """Where the stream's trackers read the next frame (None: the whole frame, as for a
    session about to start on it or a track searching for its target)."""
    regions: list[Region | None] = []
    for s in stream.sessions.values():
        if s.pending_box is not None:
            return None
        if s.tracker.initialized:
            regions.append(s.tracker.read_region())
    return cover(regions)
