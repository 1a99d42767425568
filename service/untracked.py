"""Frames on streams nobody tracks: counted, and told on the stream's error key (``no_session``).

Two ways to notice them, by where the frames travel:

* **Through the embedded router** (workers are its clients): the main process subscribes to
  every stream's frames and looks at each sample's key only, never its payload.
* **On the direct path** (``worker_listen``): frames go from a station straight to the worker
  that tracks their stream, and a subscription to every frame would draw each of them through
  the router again. The main process follows the stations' publisher tokens instead
  (``<prefix>/publishers/<stream>/<client>``, which the SDK declares from a stream's first
  frame) and tells each announced stream without a session, once a second while it lasts.
  A station that announces nothing is not told on this path. So does an instance of a fleet
  (``--mode client``), for the streams it owns: each would otherwise receive every frame.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from arcf.schemas import ErrorCode, ErrorMessage, KeySpace, encode

#: streams remembered at most, for throttling and announcements (the oldest go first):
#: frames on endless made-up stream ids cannot grow them
MAX_STREAMS = 4096
#: seconds between two notices to one stream
EVERY_S = 1.0


class UntrackedNotices:
    """Tells streams that no session tracks so (``tracked``: the streams with a session on any
    instance; ``mine``: whether this instance owns a stream, and so tells it;
    ``metrics``: :mod:`arcf.service.metrics`)."""

    def __init__(self, session: Any, keys: KeySpace, tracked: Callable[[], set[str]],
                 metrics: Any, mine: Callable[[str], bool] = lambda stream: True) -> None:
        import zenoh

        self.session = session
        self.keys = keys
        self.tracked = tracked
        self.metrics = metrics
        self.mine = mine
        self.drop = zenoh.CongestionControl.DROP
        self.put_kind = zenoh.SampleKind.PUT
        #: stream -> when it was last told
        self.told: OrderedDict[str, float] = OrderedDict()
        #: stream -> its publishers' tokens (direct path)
        self.announced: OrderedDict[str, set[str]] = OrderedDict()
        self.lock = threading.Lock()
        self._subscriber: Any = None

    # ------------------------------------------------------------------ the two sources
    def watch_frames(self) -> None:
        """Through the router: every frame's key."""
        self._subscriber = self.session.declare_subscriber(self.keys.all_frames(),
                                                           self._on_frame)

    def watch_publishers(self) -> None:
        """On the direct path: the stations' publisher tokens (:meth:`tick` tells them)."""
        self._subscriber = self.session.liveliness().declare_subscriber(
            self.keys.all_publisher_tokens(), self._on_publisher, history=True)

    def close(self) -> None:
        if self._subscriber is not None:
            self._subscriber.undeclare()

    def _on_frame(self, sample: Any) -> None:
        try:
            stream = self.keys.stream_of_frames_key(str(sample.key_expr))
        except ValueError:
            return
        if stream in self.tracked():
            return
        self.metrics.ERRORS.labels(kind=ErrorCode.NO_SESSION.value).inc()
        self._tell(stream, time.monotonic())

    def _on_publisher(self, sample: Any) -> None:
        key = str(sample.key_expr)
        try:
            stream, _ = self.keys.parse_publisher_key(key)
        except ValueError:
            return
        with self.lock:
            tokens = self.announced.pop(stream, set())
            if sample.kind == self.put_kind:
                tokens.add(key)
            else:
                tokens.discard(key)
            if tokens:
                self.announced[stream] = tokens
                while len(self.announced) > MAX_STREAMS:
                    self.announced.popitem(last=False)

    def tick(self) -> None:
        """Tell every announced stream without a session (direct path; call about once a
        second)."""
        with self.lock:
            streams = list(self.announced)
        if not streams:
            return
        tracked, now = self.tracked(), time.monotonic()
        for stream in streams:
            if stream not in tracked and self.mine(stream) and self._tell(stream, now):
                self.metrics.ERRORS.labels(kind=ErrorCode.NO_SESSION.value).inc()

    def _tell(self, stream: str, now: float) -> bool:
        """The notice, at most once per ``EVERY_S`` per stream; whether it went."""
        with self.lock:
            if now - self.told.get(stream, -EVERY_S) < EVERY_S:
                return False
            self.told[stream] = now
            self.told.move_to_end(stream)
            while len(self.told) > MAX_STREAMS:
                self.told.popitem(last=False)
        self.session.put(self.keys.errors(stream), encode(ErrorMessage(
            code=ErrorCode.NO_SESSION, stream_id=stream,
            message=f"no tracking session on stream {stream!r}")), congestion_control=self.drop)
        return True
