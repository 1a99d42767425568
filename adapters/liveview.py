"""``arcf-view``: a live view of the service in a browser: streams, sessions, boxes, signals.

    arcf-view                          # http://127.0.0.1:8090, the service on 127.0.0.1:7447
    arcf-view -e tcp/10.0.0.5:7447 --host 0.0.0.0 --port 8090 --max-fps 5 --max-width 960

A companion command, not part of the service: it listens to the streams like any station (the
service spends nothing on it) and serves one page of plain HTML and JavaScript from this
package (no build step, no CDN: it works on an offline ground station). The page lists the
live streams and their sessions (the service's ``status``) and, for the stream chosen, shows
its video with every session's box, state and confidence drawn on it, and scrolls each
session's confidence and aberrance. A session whose stream stopped (the service's ``stale``
notice) keeps its last box on the last picture, drawn thin and grey and labelled "stale: no
frames", until a result about a new frame comes.

Its cost is bounded and paid only while someone watches: a stream is listened to from the
first viewer's arrival to the last one's departure; pictures are rendered (decoded, scaled to
``--max-width``, boxes drawn, JPEG-encoded) at most ``--max-fps`` times a second, once for all
its viewers, and each viewer fetches the newest one when it has shown the last. A video
stream's access units must all be decoded while it is watched (one decoder, as in the
service). It binds to loopback unless ``--host``
says otherwise: anyone who reaches the page sees the video.

What a client can hold is bounded like the service's inputs: at most ``max_viewers``
watching connections, ``MAX_PER_CLIENT`` of them from one address; at most
``MAX_CONNECTIONS`` open connections, ``MAX_CONNECTIONS_PER_CLIENT`` from one address (more
are closed at once) with a listen backlog of
``BACKLOG``; ``TIMEOUT_S`` to send a request and to take each write (a viewer that stops
reading, or lets ``MAX_UNSENT`` bytes of events pile up unread, is dropped and its place
freed); pictures above ``max_pixels`` (from their header, before decoding) are not drawn;
a query that is not a number is ignored.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Sequence
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, generate_latest

from arcf.client import TrackingClient
from arcf.client.media.encodings import codec_of, decode_image
from arcf.client.media.video import Outcome, StreamDecoder
from arcf.schemas import Result

from ._command import add_service_arguments, connect
from .record import PALETTE
from .tap import DEFAULT_VIDEO_KEY, StreamTap, TapFrame
from .viewcontrol import ViewControl

log = logging.getLogger(__name__)
_STREAM = re.compile(r"^/api/streams/([A-Za-z0-9_.-]{1,64})/(frame\.jpg|results)$")
#: the control actions: start a session on a stream; re-initialise or stop one
_START = re.compile(r"^/api/streams/([A-Za-z0-9_.-]{1,64})/sessions$")
_SESSION = re.compile(r"^/api/sessions/([A-Za-z0-9_.-]{1,64})/(reinit|stop)$")
#: bytes a control request's body may have
MAX_BODY = 4096
_STATIC = {"/": ("view.html", "text/html; charset=utf-8"),
           "/view.js": ("view.js", "text/javascript; charset=utf-8"),
           "/view.css": ("view.css", "text/css; charset=utf-8")}
#: recent frames kept per watched stream, to draw a result on the frame it belongs to
_RECENT = 8
#: results kept per watched stream for a viewer that connects (the plot's history)
_HISTORY = 600
#: video units waiting to be decoded per watched stream (two seconds at 30 fps)
_VIDEO_QUEUE = 60
#: watching connections (pictures, results) one client address may hold
MAX_PER_CLIENT = 4
#: open connections at once (each is a thread), and from one client address; beyond, new
#: ones are closed unanswered
MAX_CONNECTIONS = 64
MAX_CONNECTIONS_PER_CLIENT = 16
#: connections the kernel queues before they are accepted
BACKLOG = 128
#: seconds a client has to send its request, and to take each write
TIMEOUT_S = 10.0
#: bytes of events a results viewer may leave unread in its socket before it is dropped
MAX_UNSENT = 256 * 1024
#: digits a number in a query may have (a picture count)
_MAX_DIGITS = 18
#: seconds a picture request waits for the next picture before answering "none yet" (204)
POLL_S = 10.0
#: seconds between a results stream's keep-alive comments while no result comes: a viewer
#: that left is found (and its place freed) by the write after next
KEEPALIVE_S = 15.0


def colour_bgr(index: int) -> tuple[int, int, int]:
    r, g, b, _ = PALETTE[index % len(PALETTE)]
    return int(255 * b), int(255 * g), int(255 * r)


#: a stale session's box and label (BGR): no session's colour, so it never reads as live
STALE_BGR = (150, 150, 150)


def draw(picture: np.ndarray, results: list[tuple[int, Result]], scale: float) -> np.ndarray:
    """The picture with each session's box (its colour; thinner unless ``tracking``) and a
    label: session, state, confidence. A result marked ``stale`` (the session's last box,
    its stream stopped since) is drawn thin and grey, labelled "stale: no frames": where the
    target was, not where it is."""
    out = picture if picture.ndim == 3 else cv2.cvtColor(picture, cv2.COLOR_GRAY2BGR)
    for index, r in results:
        if r.status.value in ("error", "stopped") or not all(np.isfinite(r.box)):
            continue
        x, y, w, h = (v * scale for v in r.box)
        x, y = x - scale, y - scale  # 1-based boxes to 0-based pixels
        if r.status.value == "stale":
            colour, thick, label = STALE_BGR, 1, f"{r.session_id[:8]} stale: no frames"
        else:
            colour = colour_bgr(index)
            state = r.track_state.value if r.track_state else r.status.value
            thick = 3 if state in ("tracking", "initialized") else 2
            conf = "" if r.confidence is None else f" {r.confidence:.2f}"
            label = f"{r.session_id[:8]} {state}{conf}"
        cv2.rectangle(out, (round(x), round(y)), (round(x + w), round(y + h)), colour, thick)
        (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
        # above the box, clear of its edge; below it where there is no room above
        ty = round(y) - 2 * thick - 3
        if ty < th + 4:
            ty = round(y + h) + 2 * thick + th + 4
        cv2.rectangle(out, (round(x), ty - th - 4), (round(x) + tw + 4, ty + 2), (0, 0, 0), -1)
        cv2.putText(out, label, (round(x) + 2, ty - 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour,
                    1, cv2.LINE_AA)
    return out


class Watch:
    """One watched stream: its frames and results heard, rendered at a capped rate."""

    def __init__(self, client: TrackingClient, stream_id: str, max_fps: float, max_width: int,
                 video_key: str | None, max_pixels: int = 4096 * 2160) -> None:
        self.stream_id = stream_id
        self.max_fps, self.max_width, self.max_pixels = max_fps, max_width, max_pixels
        self.viewers = 0
        self.changed = threading.Condition()
        #: the latest rendered picture (JPEG) and its number, for the picture viewers
        self.jpeg: bytes | None = None
        self.rendered = 0
        #: the rendered frame's key (see ``by_time``), its number in the service's numbering
        #: where the view knows it (None on the video key), and its size before scaling
        self.rendered_key: int | None = None
        self.rendered_seq: int | None = None
        self.rendered_size: tuple[int, int] | None = None
        #: frames and results are matched by capture time on the video key, by number
        #: otherwise. The video key's units carry no number: the service numbers them from
        #: its own subscription, this view from its own, so only the unit's timestamp (every
        #: result's ``capture_ts_ns``) names the same picture on both sides
        self.by_time = False
        #: the results drawn on that picture (what a viewer sees)
        self.drawn: list[Result] = []
        #: every result heard, numbered, for the results (SSE) viewers
        self.results: deque[tuple[int, str]] = deque(maxlen=_HISTORY)
        self.result_count = 0
        #: recent frames by key, oldest first
        self._frames: OrderedDict[int, TapFrame | np.ndarray] = OrderedDict()
        #: each session's recent results, oldest first
        self._by_session: dict[str, deque[Result]] = {}
        #: capture time of the video units waiting to be decoded, by the view's unit number
        self._unit_times: OrderedDict[int, int] = OrderedDict()
        #: sessions whose stream stopped (their ``stale`` notice), until a frame's result
        self._stale: dict[str, Result] = {}
        #: changes of ``_stale``: the picture is drawn again when it changes, frames or not
        self._marks = 0
        self.rendered_marks = 0
        self._colours: dict[str, int] = {}
        self._decoder: StreamDecoder | None = None
        #: video units waiting for the decoding thread (the oldest dropped beyond: the
        #: decoder sees the gap and waits for a keyframe)
        self._units: deque[TapFrame] = deque(maxlen=_VIDEO_QUEUE)
        self._unit_ready = threading.Event()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._tap = StreamTap(client, stream_id, self._on_frame, self._on_result, video_key)
        self._threads = [threading.Thread(target=self._render_loop, daemon=True,
                                          name=f"view-{stream_id}"),
                         threading.Thread(target=self._decode_loop, daemon=True,
                                          name=f"view-{stream_id}-video")]
        for thread in self._threads:
            thread.start()

    def _on_frame(self, frame: TapFrame) -> None:
        """Zenoh's callback: a video unit is queued for the decoding thread (decoding here
        would hold Zenoh's thread, and one still decoding when the process exits aborts
        it); a picture is kept as it came, decoded only if rendered."""
        if frame.source == "compressed_video":
            self.by_time = True
        if frame.is_video:
            self._units.append(frame)
            self._unit_ready.set()
            return
        self._keep(frame.capture_ts_ns if self.by_time else frame.seq, frame)

    def _decode_loop(self) -> None:
        """Every video unit through the stream's decoder, in order; the picture is kept."""
        while not self._stop.is_set():
            self._unit_ready.wait(timeout=0.5)
            self._unit_ready.clear()
            while self._units and not self._stop.is_set():
                frame = self._units.popleft()
                codec = codec_of(frame.encoding)
                if self._decoder is None or self._decoder.codec != codec.ffmpeg:
                    self._decoder = codec.stream_decoder(self.max_pixels)
                self._unit_times[frame.seq] = frame.capture_ts_ns
                while len(self._unit_times) > _VIDEO_QUEUE:
                    self._unit_times.popitem(last=False)
                out = self._decoder.decode(frame.seq, frame.payload)
                if out.outcome is Outcome.FRAME and out.image is not None:
                    seq = out.seq if out.seq is not None else frame.seq
                    key = self._unit_times.get(seq, frame.capture_ts_ns) if self.by_time else seq
                    self._keep(key, out.image)

    def _keep(self, key: int, item: TapFrame | np.ndarray) -> None:
        with self._lock:
            if self._frames and key <= next(reversed(self._frames)):
                self._frames.clear()  # a restarted numbering (or clock): the old frames go
            self._frames[key] = item
            while len(self._frames) > _RECENT:
                self._frames.popitem(last=False)

    def key_of(self, result: Result) -> int:
        """The key of the frame a result is about (``by_time``)."""
        return result.capture_ts_ns if self.by_time else result.frame_seq

    def _on_result(self, result: Result) -> None:
        with self._lock:
            self._colours.setdefault(result.session_id, len(self._colours))
            status = result.status.value
            if status == "stale":  # about no frame: marks the session, draws nothing new
                if result.session_id not in self._stale:
                    self._marks += 1
                self._stale[result.session_id] = result
            elif self._stale.pop(result.session_id, None) is not None:
                self._marks += 1  # a frame's result (or its end): no longer stale
            if status == "stopped":  # nothing more to wait for or to draw
                self._by_session.pop(result.session_id, None)
            elif status != "stale":
                self._by_session.setdefault(result.session_id,
                                            deque(maxlen=_RECENT)).append(result)
        event = json.dumps({
            "session_id": result.session_id, "frame_seq": result.frame_seq,
            "status": result.status.value, "box": _finite(result.box),
            "message": result.message, "code": result.code.value if result.code else None,
            "state": result.track_state.value if result.track_state else None,
            "confidence": result.confidence, "aberrance": _finite([result.aberrance])[0],
            "colour": "#" + bytes(colour_bgr(self._colours[result.session_id])[::-1]).hex()})
        with self.changed:
            self.result_count += 1
            self.results.append((self.result_count, event))
            self.changed.notify_all()

    def _pick(self) -> tuple[int, TapFrame | np.ndarray, list[tuple[int, Result]]] | None:
        """The frame to render, by key: the newest one every session has answered (so the
        boxes are that frame's), else, for a stream without answers, the newest one. A
        session whose last answer is older than every frame kept (it lags far behind, or
        ended unseen) does not hold the picture back. The same frame again when a session
        went stale or came back (its box is drawn differently); a stale session's last
        result is marked ``stale`` (its notice's status and message, its own box)."""
        with self._lock:
            if not self._frames:
                return None
            oldest = next(iter(self._frames))
            last = {sid: max(self.key_of(r) for r in recent)
                    for sid, recent in self._by_session.items() if recent}
            answered = [k for k in last.values() if k >= oldest]
            candidates = [k for k in self._frames if not answered or k <= min(answered)]
            key = max(candidates) if candidates else next(reversed(self._frames))
            if key == self.rendered_key and self._marks == self.rendered_marks:
                return None
            self.rendered_marks = self._marks
            results = []
            for sid, recent in self._by_session.items():
                older = [r for r in recent if self.key_of(r) <= key]
                if older:
                    r = max(older, key=self.key_of)
                    notice = self._stale.get(sid)
                    if notice is not None:
                        r = r.model_copy(update={"status": notice.status,
                                                 "message": notice.message})
                    results.append((self._colours[sid], r))
            return key, self._frames[key], results

    def _render_loop(self) -> None:
        period = 1.0 / self.max_fps
        while not self._stop.wait(period):
            picked = self._pick()
            if picked is None:
                continue
            key, item, results = picked
            try:
                picture = (item if isinstance(item, np.ndarray)
                           else _picture(item, self.max_pixels))
            except ValueError as exc:
                log.debug("frame %d of %s not drawn: %s", key, self.stream_id, exc)
                continue
            size = (int(picture.shape[1]), int(picture.shape[0]))
            scale = min(1.0, self.max_width / picture.shape[1])
            if scale < 1.0:
                picture = cv2.resize(picture, None, fx=scale, fy=scale,
                                     interpolation=cv2.INTER_AREA)
            else:
                picture = picture.copy()
            ok, buf = cv2.imencode(".jpg", draw(picture, results, scale),
                                   [cv2.IMWRITE_JPEG_QUALITY, 85])
            if not ok:
                continue
            with self.changed:
                self.jpeg, self.rendered_key, self.rendered_size = buf.tobytes(), key, size
                self.rendered_seq = None if self.by_time else key
                self.drawn = [r for _, r in results]
                self.rendered += 1
                self.changed.notify_all()

    def close(self) -> None:
        self._stop.set()
        self._tap.close()
        self._unit_ready.set()
        with self.changed:
            self.changed.notify_all()
        for thread in self._threads:
            thread.join(timeout=5)


def _finite(values: Sequence[float]) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in values]


def _picture(frame: TapFrame, max_pixels: int) -> np.ndarray:
    """A frame's pixels, checked and decoded as a worker does (the encoding table);
    ``ValueError`` when it cannot be read or declares more than ``max_pixels`` (read from its
    header: a decompression bomb is never decoded)."""
    pixels, problem = decode_image(frame, max_pixels)
    if pixels is None:
        raise ValueError(problem[1] if problem else f"cannot decode {frame.encoding} frame")
    assert isinstance(pixels, np.ndarray)  # no region asked for: the whole picture
    return pixels


class LiveView:
    """The page's HTTP server and the streams being watched."""

    def __init__(self, client: TrackingClient, host: str = "127.0.0.1", port: int = 8090, *,
                 max_fps: float = 5.0, max_width: int = 960,
                 video_key: str | None = DEFAULT_VIDEO_KEY, max_viewers: int = 16,
                 max_pixels: int = 4096 * 2160, allow_control: bool = False,
                 allowed_hosts: Sequence[str] = (), control_token: str | None = None) -> None:
        if not (0 < max_fps <= 30 and 64 <= max_width <= 4096 and max_viewers >= 1
                and max_pixels >= 1):
            raise ValueError("max_fps must be in (0, 30], max_width in [64, 4096], "
                             "max_viewers and max_pixels >= 1")
        self.client = client
        self.max_fps, self.max_width, self.video_key = max_fps, max_width, video_key
        self.max_viewers, self.max_pixels = max_viewers, max_pixels
        self.watches: dict[str, Watch] = {}
        self._lock = threading.Lock()
        self._viewers = 0
        #: watching connections per client address
        self._by_client: dict[str, int] = {}
        #: what was refused or dropped, by reason (for tests and logs); the same on the
        #: page's ``/metrics`` (Prometheus), ``arcf_view_events_total{reason}``
        self.counts: dict[str, int] = {}
        self.registry = CollectorRegistry()
        self._events_total = Counter(
            "arcf_view_events_total", "Requests the live view refused (control_<code>: "
            "control requests, by their code) and viewers it refused or dropped, by reason",
            ["reason"], registry=self.registry)
        self._status: tuple[float, bytes] = (0.0, b"")
        self.control = ViewControl(client, enabled=allow_control, allowed_hosts=allowed_hosts,
                                   count=self.count, token=control_token)
        view = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"
            timeout = TIMEOUT_S  # the socket's: reading the request, and every write

            def log_message(self, fmt: str, *args: Any) -> None:
                log.debug("%s " + fmt, self.address_string(), *args)

            def do_GET(self) -> None:
                view.handle(self)

            def do_POST(self) -> None:
                view.handle_post(self)

        self.server = _BoundedServer((host, port), Handler, self)
        self.server.daemon_threads = True
        self.port = self.server.server_address[1]
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True,
                                        name="liveview-http")
        self._thread.start()

    @property
    def url(self) -> str:
        host = str(self.server.server_address[0])
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.port}/"

    @property
    def control_url(self) -> str:
        """The page's address with the control token in its fragment (what the operator
        opens to control tracking; ``url`` alone only watches)."""
        return f"{self.url}#token={self.control.token}"

    # ------------------------------------------------------------------ watching
    def count(self, reason: str) -> None:
        with self._lock:
            self.counts[reason] = self.counts.get(reason, 0) + 1
        self._events_total.labels(reason=reason).inc()

    def _watch(self, stream_id: str, client: str) -> Watch | str:
        """The stream's watch, with one more viewer; or why not (a 503's text)."""
        with self._lock:
            if self._viewers >= self.max_viewers:
                return "too many viewers"
            if self._by_client.get(client, 0) >= MAX_PER_CLIENT:
                return f"too many viewers from {client} (at most {MAX_PER_CLIENT})"
            self._viewers += 1
            self._by_client[client] = self._by_client.get(client, 0) + 1
            watch = self.watches.get(stream_id)
            if watch is None:
                watch = self.watches[stream_id] = Watch(
                    self.client, stream_id, self.max_fps, self.max_width, self.video_key,
                    self.max_pixels)
            watch.viewers += 1
            return watch

    def _unwatch(self, watch: Watch, client: str) -> None:
        with self._lock:
            self._viewers -= 1
            left = self._by_client[client] - 1
            if left:
                self._by_client[client] = left
            else:
                del self._by_client[client]
            watch.viewers -= 1
            if watch.viewers == 0:
                del self.watches[watch.stream_id]
            else:
                return
        watch.close()  # the last viewer left: stop listening

    # ------------------------------------------------------------------ HTTP
    def handle(self, req: BaseHTTPRequestHandler) -> None:
        path = req.path.split("?", 1)[0]
        if path in _STATIC:
            name, kind = _STATIC[path]
            self._send(req, HTTPStatus.OK, kind,
                       resources.files("arcf.adapters").joinpath("static", name).read_bytes())
        elif path == "/api/streams":
            self._send(req, HTTPStatus.OK, "application/json", self._streams())
        elif path == "/api/config":
            self._send(req, HTTPStatus.OK, "application/json",
                       json.dumps(self.control.config()).encode())
        elif path == "/metrics":
            self._send(req, HTTPStatus.OK, CONTENT_TYPE_LATEST, generate_latest(self.registry))
        elif (m := _STREAM.match(path)) is not None:
            client = req.client_address[0]
            watch = self._watch(m.group(1), client)
            if isinstance(watch, str):
                self.count("refused_viewer")
                self._send(req, HTTPStatus.SERVICE_UNAVAILABLE, "text/plain",
                           watch.encode() + b"\n")
                return
            try:
                if m.group(2) == "frame.jpg":
                    self._frame(req, watch)
                else:
                    self._events(req, watch)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the viewer left
            except (TimeoutError, _SlowReader):
                self.count("slow_viewer")  # it stopped reading: its place is freed
                req.close_connection = True
            finally:
                self._unwatch(watch, client)
        else:
            self._send(req, HTTPStatus.NOT_FOUND, "text/plain", b"not found\n")

    def handle_post(self, req: BaseHTTPRequestHandler) -> None:
        """A control request (``viewcontrol``): start a session on a stream, re-initialise
        or stop a session. Its body is read only when its length is declared and small."""
        path = req.path.split("?", 1)[0]
        if (m := _START.match(path)) is not None:
            action, target = "start", m.group(1)
        elif (m := _SESSION.match(path)) is not None:
            action, target = m.group(2), m.group(1)
        else:
            self._send(req, HTTPStatus.NOT_FOUND, "text/plain", b"not found\n")
            return
        length = req.headers.get("Content-Length", "0")
        if not length.isdigit() or int(length) > MAX_BODY:
            self.count("control_bad_request")
            req.close_connection = True  # the body is not read: the connection cannot go on
            self._send(req, HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "application/json",
                       json.dumps({"code": "bad_request", "message": f"a control request's "
                                   f"body has a length of at most {MAX_BODY} bytes"}).encode())
            return
        try:
            body = req.rfile.read(int(length))
        except (TimeoutError, ConnectionError):
            self.count("slow_viewer")
            req.close_connection = True
            return
        headers = {k: req.headers.get(k, "") for k in ("Host", "Content-Type",
                                                        "Authorization")}
        if "Origin" in req.headers:
            headers["Origin"] = req.headers["Origin"]
        reply = self.control.handle(action, target, headers, body)
        if reply.status < 300:
            self._status = (0.0, b"")  # the stream list shows the change at once
        self._send(req, reply.status, "application/json", json.dumps(reply.body).encode())

    def _send(self, req: BaseHTTPRequestHandler, status: HTTPStatus, kind: str,
              body: bytes) -> None:
        req.send_response(status)
        req.send_header("Content-Type", kind)
        req.send_header("Content-Length", str(len(body)))
        req.send_header("Cache-Control", "no-store")
        req.end_headers()
        req.wfile.write(body)

    def _streams(self) -> bytes:
        """Streams and sessions from the service's status, with the streams stations announce
        publishing (no session yet), cached for a second."""
        at, body = self._status
        if time.monotonic() - at < 1.0:
            return body
        try:
            status = self.client.status(timeout=2.0)
            streams: dict[str, list[dict[str, Any]]] = {
                name: [] for name in self.client.streams(timeout=1.0)}
            for s in status.sessions:
                streams.setdefault(s.stream_id, []).append({
                    "session_id": s.session_id, "preset": s.preset,
                    "state": str(getattr(s.state, "value", s.state)) if s.state else None,
                    "frames": s.frames,
                    "last_seq": s.last_seq})
            doc: dict[str, Any] = {"streams": [{"stream_id": k, "sessions": v}
                                               for k, v in sorted(streams.items())]}
        except Exception as exc:  # the page says so instead of failing
            doc = {"streams": [], "error": f"no answer from the service: {exc}"}
        body = json.dumps(doc).encode()
        self._status = (time.monotonic(), body)
        return body

    def _frame(self, req: BaseHTTPRequestHandler, watch: Watch) -> None:
        """The next rendered picture after ``?after=N`` (a long poll: it waits up to 10 s for
        one), its number, its frame's number and size in headers. The page asks again once it
        shows it, so a slow viewer gets fewer pictures instead of a backlog, and every picture
        shown is complete (a browser's multipart/MJPEG decoding shows a part late)."""
        query = req.path.partition("?")[2]
        after = -1
        for part in query.split("&"):
            key, _, value = part.partition("=")
            digits = value[1:] if value.startswith("-") else value
            if key == "after" and digits.isdigit() and len(digits) <= _MAX_DIGITS:
                after = int(value)
        with watch.changed:
            watch.changed.wait_for(lambda: watch.rendered > after or watch._stop.is_set(),
                                   timeout=POLL_S)
            jpeg, rendered, seq = watch.jpeg, watch.rendered, watch.rendered_seq
            size = watch.rendered_size
        if jpeg is None or rendered <= after:
            req.send_response(HTTPStatus.NO_CONTENT)
            req.send_header("Content-Length", "0")
            req.end_headers()
            return
        req.send_response(HTTPStatus.OK)
        req.send_header("Content-Type", "image/jpeg")
        req.send_header("Content-Length", str(len(jpeg)))
        req.send_header("Cache-Control", "no-store")
        req.send_header("X-Rendered", str(rendered))
        if seq is not None:  # the service's number of the frame (not known on the video key)
            req.send_header("X-Frame-Seq", str(seq))
        if size is not None:  # the frame's own size: a box drawn on the picture scales by it
            req.send_header("X-Frame-Width", str(size[0]))
            req.send_header("X-Frame-Height", str(size[1]))
        req.end_headers()
        req.wfile.write(jpeg)

    def _events(self, req: BaseHTTPRequestHandler, watch: Watch) -> None:
        """Server-sent events: the stream's results as they arrive (recent history first)."""
        req.send_response(HTTPStatus.OK)
        req.send_header("Content-Type", "text/event-stream")
        req.send_header("Cache-Control", "no-store")
        req.send_header("Connection", "close")
        req.end_headers()
        sent = 0
        while not watch._stop.is_set():
            with watch.changed:
                def news(sent: int = sent) -> bool:
                    return watch.result_count != sent or watch._stop.is_set()

                watch.changed.wait_for(news, timeout=KEEPALIVE_S)
                fresh = [(n, e) for n, e in watch.results if n > sent]
            if not fresh:
                req.wfile.write(b": keep-alive\n\n")  # finds a viewer that left
            for n, event in fresh:
                req.wfile.write(b"data: " + event.encode() + b"\n\n")
                sent = n
            req.wfile.flush()
            if _unsent(req.connection) > MAX_UNSENT:
                raise _SlowReader

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        for watch in list(self.watches.values()):
            watch.close()


class _SlowReader(Exception):
    """A results viewer left more than ``MAX_UNSENT`` bytes unread."""


def _unsent(sock: Any) -> int:
    """Bytes written to ``sock`` that its peer has not taken yet (Linux's TIOCOUTQ: 0 where
    it cannot be read, and a viewer is then dropped only by the write timeout)."""
    try:
        import fcntl
        import termios

        raw = fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0")
        return int.from_bytes(raw, "little", signed=True)
    except (ImportError, OSError, AttributeError):
        return 0


class _BoundedServer(ThreadingHTTPServer):
    """A thread per connection, at most ``MAX_CONNECTIONS`` of them and
    ``MAX_CONNECTIONS_PER_CLIENT`` from one address: a connection beyond is closed at once
    (counted), so half-sent requests cannot take every thread and memory, nor one client
    every place."""

    request_queue_size = BACKLOG

    def __init__(self, address: tuple[str, int], handler: Any, view: LiveView) -> None:
        super().__init__(address, handler)
        self.view = view
        self._open = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self._lock = threading.Lock()
        self._by_client: dict[str, int] = {}

    def process_request(self, request: Any, client_address: Any) -> None:
        client = client_address[0]
        with self._lock:
            mine = self._by_client.get(client, 0)
            if mine < MAX_CONNECTIONS_PER_CLIENT and self._open.acquire(blocking=False):
                self._by_client[client] = mine + 1
                admitted = True
            else:
                admitted = False
        if not admitted:
            self.view.count("refused_connection")
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except Exception:
            self._release(client)
            raise

    def _release(self, client: str) -> None:
        with self._lock:
            left = self._by_client[client] - 1
            if left:
                self._by_client[client] = left
            else:
                del self._by_client[client]
            self._open.release()

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._release(client_address[0])


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="arcf-view", description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.1",
                    help="address to serve on (default loopback only)")
    ap.add_argument("--port", type=int, default=8090)
    ap.add_argument("--max-fps", type=float, default=5.0,
                    help="pictures rendered per second and stream, at most (default 5)")
    ap.add_argument("--max-width", type=int, default=960,
                    help="pictures scaled down to this width, at most (default 960)")
    ap.add_argument("--max-viewers", type=int, default=16,
                    help=f"watching connections at once (default 16; {MAX_PER_CLIENT} per "
                    "client address)")
    ap.add_argument("--max-pixels", type=int, default=4096 * 2160,
                    help="largest picture drawn, from its header (default: %(default)s, "
                    "DCI 4K)")
    ap.add_argument("--video-key", default=DEFAULT_VIDEO_KEY,
                    help="the service's video_key ('' for none)")
    ap.add_argument("--allow-control", action="store_true",
                    help="let the page start, re-initialise and stop sessions (drawing a box "
                    "on the video); off by default: whoever reaches the page controls tracking")
    ap.add_argument("--control-token-file", type=Path, metavar="PATH",
                    help="the control token (its first line, at least 16 characters), for a "
                    "deployment that hands it to its operators; default: a random one, printed "
                    "with the page's address")
    ap.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                    help="a host name the page may be reached by for control (repeatable; IP "
                    "addresses and localhost always may)")
    add_service_arguments(ap)
    args = ap.parse_args(argv)
    token = None
    if args.control_token_file is not None:
        try:
            token = args.control_token_file.read_text().splitlines()[0].strip()
        except (OSError, IndexError) as exc:
            raise SystemExit(f"arcf-view: no control token in {args.control_token_file}: "
                             f"{exc}") from exc
    client, stop = connect(args, log)
    if client is None:
        return 2
    with client:
        try:
            view = LiveView(client, args.host, args.port, max_fps=args.max_fps,
                            max_width=args.max_width, video_key=args.video_key or None,
                            max_viewers=args.max_viewers, max_pixels=args.max_pixels,
                            allow_control=args.allow_control, allowed_hosts=args.allow_host,
                            control_token=token)
        except (OSError, ValueError) as exc:
            raise SystemExit(f"arcf-view: {exc}") from exc
        if args.allow_control:
            # the operator's link: the token rides in the fragment, which no server sees
            print(f"arcf-view: open {view.control_url} to control tracking ({view.url} "
                  "only watches)", flush=True)
        log.info("live view on %s (tracking control %s)", view.url,
                 "on, with the token" if args.allow_control
                 else "off: --allow-control turns it on")
        stop.wait()
        view.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
