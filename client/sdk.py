"""Client SDK for ground stations: publish frames, control sessions, receive results.

    from arcf.client import TrackingClient
    with TrackingClient() as client:                      # connects to tcp/127.0.0.1:7447
        results = client.results("drone-1")                # subscribe before starting
        ack = client.start("drone-1", (x, y, w, h), preset="arcf-hc")
        client.publish_frame("drone-1", image)            # numpy BGR/gray, or encoded bytes
        for r in results.iter(timeout=1.0):
            print(r.frame_seq, r.box, r.peak, r.aberrance)
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Generic, TypeVar

import numpy as np
import zenoh

from arcf.schemas import (
    Ack,
    ErrorMessage,
    Frame,
    InvalidKey,
    KeySpace,
    Message,
    Presets,
    PresetsRequest,
    ReinitRequest,
    Result,
    StartRequest,
    Status,
    StatusRequest,
    StopRequest,
    decode,
    encode,
)

from .media.encodings import VIDEO_ENCODINGS, encode_image
from .transport import open_session

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)


class ServiceError(RuntimeError):
    """The service answered a request with an error (``code`` says which)."""

    def __init__(self, error: ErrorMessage) -> None:
        self.code: str = getattr(error.code, "value", str(error.code))
        super().__init__(f"{self.code}: {error.message}")  # "invalid_parameter: ...", the wire's
        self.error = error


class MessageStream(Generic[M]):
    """Messages of one key expression (results of a stream or a session, a stream's frames or
    errors), received by a callback or iterated. What does not validate is counted and
    skipped."""

    def __init__(self, client: TrackingClient, key: str,
                 callback: Callable[[M], None] | None, maxsize: int,
                 expected: type[M]) -> None:
        self._queue: queue.Queue[M] = queue.Queue(maxsize=maxsize)
        self.dropped = 0
        self.malformed = 0
        limit = client.max_payload

        def on_sample(sample: Any) -> None:
            try:
                message = decode(sample.payload.to_bytes(), expected=expected,
                                 max_payload=limit)
            except ValueError:
                self.malformed += 1
                return
            if callback is not None:
                callback(message)
                return
            try:
                self._queue.put_nowait(message)
            except queue.Full:
                self.dropped += 1

        self._sub = client.session.declare_subscriber(key, on_sample)

    def get(self, timeout: float | None = None) -> M:
        """The next message; raises ``queue.Empty`` after ``timeout`` seconds."""
        return self._queue.get(timeout=timeout)

    def iter(self, timeout: float = 1.0) -> Iterator[M]:
        """Messages until none arrives for ``timeout`` seconds."""
        while True:
            try:
                yield self._queue.get(timeout=timeout)
            except queue.Empty:
                return

    def close(self) -> None:
        self._sub.undeclare()


#: Results of a stream or a session (what ``TrackingClient.results`` returns).
ResultStream = MessageStream[Result]


class TrackingClient:
    def __init__(
        self,
        connect: Sequence[str] = ("tcp/127.0.0.1:7447",),
        prefix: str = "arcf/v1",
        mode: str = "client",
        session: zenoh.Session | None = None,
        client_id: str | None = None,
        tie_sessions: bool = True,
        max_payload: int = 8 * 1024 * 1024,
        frame_congestion: str = "drop",
        video_history: int = 150,
    ) -> None:
        """``tie_sessions``: declare this station's liveliness token and name it in every
        ``start``, so that the service ends the sessions it started when the station is gone
        (closed, killed or cut off) for longer than the service's grace period.
        ``max_payload``: the service's limit (its default here); a larger frame is refused
        before it is sent.
        ``frame_congestion``: ``"drop"`` (live video: a frame that finds no room on a link
        within Zenoh's wait, 1 ms, is dropped, by this station's session or by a router on the
        way, and counted by the service in the next result's ``dropped``; a starved CPU can
        cause that too, about 1 frame in 1,000 measured on a 2-core machine running 4 busy
        loops), or ``"block"`` (replays, recordings, tests: a frame waits for room, so
        ``publish_frame`` may stall on a slow link, but no frame is lost).
        ``video_history``: the last access units of each video stream (h264 / h265) this
        station keeps for the service (zenoh-ext's advanced publisher and its cache). A worker
        that subscribes to the stream when a session starts gets them first and decodes from
        their keyframe, so that the box lands on the picture it was drawn on instead of
        waiting for the next keyframe: enough for a group of pictures plus the frames between
        the pilot's click and the session's start (150: 5 s at 30 fps). The service asks
        for at most its ``video_history`` (300), none older than 10 s. It needs Zenoh's
        timestamping on the session, which sessions opened here have; on a ``session`` given
        without it, a plain publisher is used, saying so. 0: none kept."""
        if frame_congestion not in ("drop", "block"):
            raise ValueError(f"frame_congestion must be 'drop' or 'block', got "
                             f"{frame_congestion!r}")
        self._congestion = (zenoh.CongestionControl.DROP if frame_congestion == "drop"
                            else zenoh.CongestionControl.BLOCK)
        self.max_payload = max_payload
        self.keys = KeySpace(prefix)
        self._own = session is None
        self.session = session if session is not None else open_session(
            mode, connect=connect, timestamping=True)
        self.video_history = video_history
        self.client_id = client_id or uuid.uuid4().hex
        self._token = (self.session.liveliness().declare_token(
            self.keys.client_token(self.client_id)) if tie_sessions else None)
        self._publishers: dict[str, Any] = {}
        self._announced: dict[str, Any] = {}
        self._seq: dict[str, int] = {}
        self._lock = threading.Lock()
        #: the control token of each session this client started (or was given), which its
        #: stop and reinit carry: persist it to adopt the sessions after a restart
        self.control_tokens: dict[str, str] = {}

    # ------------------------------------------------------------------ frames
    def publish_frame(
        self,
        stream_id: str,
        image: np.ndarray | None = None,
        *,
        data: bytes | None = None,
        encoding: str = "jpeg",
        seq: int | None = None,
        capture_ts_ns: int | None = None,
        quality: int = 90,
        size: tuple[int, int] | None = None,
    ) -> int:
        """Publish one frame (a numpy image, encoded here, or already encoded ``data``).

        Returns its sequence number (consecutive per stream unless given). Frames are sent with
        the client's ``frame_congestion`` (default DROP: a slow link loses frames rather than
        stalling the station). ``size``: the (width, height) of encoded ``data`` where the
        sender knows it (a video unit's, from its stream's parameters), declared in the frame
        for stations that show or convert boxes without decoding (required for raw data).
        """
        if (image is None) == (data is None):
            raise ValueError("give either image or data")
        width, height = size if size is not None and data is not None else (None, None)
        if image is not None:
            height, width = image.shape[:2]
            data = encode_image(image, encoding, quality)
        assert data is not None  # given, or encoded just above
        if len(data) > self.max_payload:
            raise ValueError(f"a frame of {len(data)} bytes is above max_payload "
                             f"({self.max_payload}): the service would refuse it, and a "
                             "frame far larger may not even cross the link")
        with self._lock:
            if seq is None:
                seq = self._seq.get(stream_id, -1) + 1
            self._seq[stream_id] = seq
            pub = self._publishers.get(stream_id)
            if pub is None:
                pub = self._publishers[stream_id] = self._declare_frames(stream_id, encoding)
                # announced while this client publishes it: viewers list it before any
                # session tracks it (``streams``)
                self._announced[stream_id] = self.session.liveliness().declare_token(
                    self.keys.publisher_token(stream_id, self.client_id))
        frame = Frame(stream_id=stream_id, seq=seq,
                      capture_ts_ns=capture_ts_ns if capture_ts_ns is not None else time.time_ns(),
                      encoding=encoding, width=width, height=height, payload=data)
        pub.put(encode(frame))
        return seq

    def _declare_frames(self, stream_id: str, encoding: str) -> Any:
        """A stream's frame publisher: a video stream's keeps its last ``video_history``
        units for a worker that subscribes late (see ``__init__``)."""
        key = self.keys.frames(stream_id)
        if encoding in VIDEO_ENCODINGS and self.video_history > 0:
            import zenoh.ext

            try:
                return zenoh.ext.declare_advanced_publisher(
                    self.session, key, congestion_control=self._congestion,
                    cache=zenoh.ext.CacheConfig(max_samples=self.video_history))
            except zenoh.ZError as exc:  # a session without timestamping
                log.warning("stream %r: its recent video is not kept for the service (%s); "
                            "a session started between keyframes waits for the next one",
                            stream_id, exc)
        return self.session.declare_publisher(key, congestion_control=self._congestion)

    # ------------------------------------------------------------------ control
    def _request(self, request: Any, timeout: float) -> Any:
        # target ALL: with several instances, each sees the request and the one that owns it
        # answers (see service.control)
        replies = list(self.session.get(self.keys.control(), payload=encode(request),
                                        timeout=timeout, target=zenoh.QueryTarget.ALL))
        for reply in replies:
            if reply.ok is None:
                continue
            message = decode(reply.ok.payload.to_bytes(),
                             expected=(Ack, ErrorMessage, Status, Presets))
            if isinstance(message, ErrorMessage):
                raise ServiceError(message)
            return message
        raise TimeoutError(f"no reply from the service on {self.keys.control()} within "
                           f"{timeout} s (is arcf-service running and reachable?)")

    def start(self, stream_id: str, box: Sequence[float], preset: str = "arcf-hc", *,
              overrides: dict[str, Any] | None = None, session_id: str | None = None,
              frame_seq: int | None = None, timeout: float = 5.0) -> Ack:
        """Start a session. Its ack carries the session's control token, kept in
        :attr:`control_tokens`: this client's :meth:`stop` and :meth:`reinit` send it."""
        ack = self._request(StartRequest(
            request_id=uuid.uuid4().hex, stream_id=stream_id, session_id=session_id,
            box=list(box), preset=preset, overrides=overrides or {}, frame_seq=frame_seq,
            client_id=self.client_id if self._token is not None else None), timeout)
        if ack.session_id is not None and ack.control_token is not None:
            self.control_tokens[ack.session_id] = ack.control_token
        return ack

    def reinit(self, session_id: str, box: Sequence[float], *, frame_seq: int | None = None,
               adopt: bool = False, control_token: str | None = None,
               timeout: float = 5.0) -> Ack:
        """``adopt``: this station takes the session over, so that its lifetime follows this
        client's liveliness token from now on (a restarted station adopting the sessions its
        previous run left behind, found with :meth:`status`, with the control tokens it
        kept). A station with a stable ``client_id`` needs no adoption: its sessions are
        already its own. ``control_token``: the session's, where this client did not start
        it (kept for the session from then on)."""
        if adopt and self._token is None:
            raise ValueError("adopt needs a client that ties its sessions (tie_sessions=True)")
        if control_token is not None:
            self.control_tokens[session_id] = control_token
        return self._request(ReinitRequest(
            request_id=uuid.uuid4().hex, session_id=session_id, box=list(box),
            frame_seq=frame_seq, client_id=self.client_id if adopt else None,
            control_token=self.control_tokens.get(session_id)), timeout)

    def stop(self, session_id: str, *, control_token: str | None = None,
             timeout: float = 5.0) -> Ack:
        """Stop a session, with its control token (this client's own, or ``control_token``)."""
        ack = self._request(StopRequest(
            request_id=uuid.uuid4().hex, session_id=session_id,
            control_token=control_token or self.control_tokens.get(session_id)), timeout)
        self.control_tokens.pop(session_id, None)
        return ack

    def presets(self, timeout: float = 5.0) -> Presets:
        """The service's presets and what each override accepts."""
        return self._request(PresetsRequest(request_id=uuid.uuid4().hex), timeout)

    def check(self, preset: str, overrides: dict[str, Any] | None = None,
              timeout: float = 5.0) -> None:
        """Whether a start with ``preset`` and ``overrides`` would be accepted, checked by
        the service as a start is (nothing started): raises :class:`ServiceError` with the
        code and reason a start would get (``unknown_preset``, ``invalid_parameter``)."""
        reply: Presets = self._request(PresetsRequest(
            request_id=uuid.uuid4().hex, preset=preset, overrides=overrides or {}), timeout)
        if reply.refused is not None:
            raise ServiceError(ErrorMessage(code=reply.refused, message=reply.refusal or "",
                                            request_id=reply.request_id))

    def status(self, stream_id: str | None = None, timeout: float = 5.0) -> Status:
        """What the service runs (only ``stream_id``'s sessions, if given)."""
        return self._request(StatusRequest(request_id=uuid.uuid4().hex, stream_id=stream_id),
                             timeout)

    # ------------------------------------------------------------------ results
    def results(self, stream_id: str, session_id: str | None = None,
                callback: Callable[[Result], None] | None = None,
                maxsize: int = 10000) -> ResultStream:
        key = (self.keys.results(stream_id, session_id) if session_id
               else self.keys.results_of_stream(stream_id))
        return MessageStream(self, key, callback, maxsize, Result)

    def errors(self, stream_id: str,
               callback: Callable[[ErrorMessage], None] | None = None,
               maxsize: int = 1000) -> MessageStream[ErrorMessage]:
        """Watch what the service refuses of a stream's frames (``<prefix>/streams/<stream>/
        errors``: rate limited, oversized, undecodable, out of order, a jump in the numbering),
        one notice per code and second at most, each refused frame counted in the metrics. A
        frame refused here has no result; the next result's ``dropped`` counts it."""
        return MessageStream(self, self.keys.errors(stream_id), callback, maxsize,
                             ErrorMessage)

    def frames(self, stream_id: str, callback: Callable[[Frame], None] | None = None,
               maxsize: int = 8) -> MessageStream[Frame]:
        """Watch a stream's frames as the service receives them (whoever publishes them):
        adapters learn a stream's frame size and numbering from it. Without a callback, frames
        wait in a queue of ``maxsize``; while it is full, newer ones are dropped (counted in
        ``dropped``)."""
        return MessageStream(self, self.keys.frames(stream_id), callback, maxsize, Frame)

    def streams(self, timeout: float = 2.0) -> list[str]:
        """The streams some station publishes now (its SDK announces each one while its
        client is open; a stream fed otherwise, e.g. only on the video key, is not listed),
        sorted."""
        found = set()
        for reply in self.session.liveliness().get(self.keys.all_publisher_tokens(),
                                                  timeout=timeout):
            if reply.ok is None:
                continue
            try:
                found.add(self.keys.parse_publisher_key(reply.ok.key_expr)[0])
            except InvalidKey:
                continue
        return sorted(found)

    def close(self) -> None:
        for token in self._announced.values():
            token.undeclare()
        for pub in self._publishers.values():
            pub.undeclare()
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        if self._own:
            self.session.close()

    def __enter__(self) -> TrackingClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
