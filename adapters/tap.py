"""Listening in on one stream: its frames (in either convention) and its sessions' results.

The recorder and the live view see a stream as the service does, without taking part: the
``frame`` messages on ``<prefix>/streams/<stream>/frames`` (pictures or video access units),
the CDR ``foxglove.CompressedVideo`` units on the service's ``video_key`` (numbered in arrival
order, as the service numbers them), and every ``result`` of the stream's sessions. A
``StreamTap`` turns both frame conventions into one ``TapFrame`` and hands frames and results
to callbacks, on Zenoh's threads: callbacks must be quick (copy, queue, return).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from arcf.client import TrackingClient
from arcf.client.foxglove import parse_compressed_video
from arcf.client.media.encodings import video_codec
from arcf.schemas import Frame, Result

log = logging.getLogger(__name__)

#: the service's default ``video_key``
DEFAULT_VIDEO_KEY = "video/{stream}/stream"


@dataclass(frozen=True)
class TapFrame:
    """One frame of a stream, whichever way it came."""

    stream_id: str
    seq: int
    capture_ts_ns: int
    #: ``jpeg`` | ``png`` | ``bgr8`` | ``gray8`` | ``h264`` | ``h265``
    encoding: str
    payload: bytes
    width: int | None = None
    height: int | None = None
    #: ``frame`` (the service's own message) or ``compressed_video`` (the camera manager's)
    source: str = "frame"

    @property
    def is_video(self) -> bool:
        return video_codec(self.encoding) is not None


class StreamTap:
    """Subscribers on one stream's frames, video key and results, until ``close``."""

    def __init__(self, client: TrackingClient, stream_id: str,
                 on_frame: Callable[[TapFrame], None], on_result: Callable[[Result], None],
                 video_key: str | None = DEFAULT_VIDEO_KEY) -> None:
        self.stream_id = stream_id
        self.malformed = 0
        self._lock = threading.Lock()
        self._video_seq = 0

        def frame(f: Frame) -> None:
            on_frame(TapFrame(stream_id, f.seq, f.capture_ts_ns, f.encoding.value,
                              f.payload, f.width, f.height))

        def video(sample: Any) -> None:
            with self._lock:  # numbered in arrival order, refused ones included (as the service)
                seq, self._video_seq = self._video_seq, self._video_seq + 1
            try:
                unit = parse_compressed_video(sample.payload.to_bytes())
            except ValueError:
                self.malformed += 1
                return
            if video_codec(unit.format) is None:
                self.malformed += 1
                return
            on_frame(TapFrame(stream_id, seq, unit.timestamp_ns, unit.format, unit.data,
                              source="compressed_video"))

        self._frames = client.frames(stream_id, callback=frame)
        self._results = client.results(stream_id, callback=on_result)
        self._video = (client.session.declare_subscriber(
            video_key.replace("{stream}", stream_id), video) if video_key else None)

    def close(self) -> None:
        """Undeclare the subscribers (already gone with a closed client: nothing to do)."""
        for undeclare in (self._frames.close, self._results.close,
                          self._video.undeclare if self._video is not None else None):
            if undeclare is None:
                continue
            try:
                undeclare()
            except Exception:  # the client's session closed first
                log.debug("subscriber of %s already gone", self.stream_id, exc_info=True)
