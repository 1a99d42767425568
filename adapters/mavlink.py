"""MAVLink: the tracking service as one MAVLink camera per video stream.

Ground stations (QGroundControl's click-and-drag on the video, MAVProxy's ``camtrack``, Mission
Planner) ask a camera to track with MAVLink's camera protocol, and ArduPilot forwards those
commands to a component that advertises tracking. :class:`MavlinkCameras` is that component,
for each configured stream of the service:

* it sends a ``HEARTBEAT`` per camera (``MAV_TYPE_CAMERA``) and answers
  ``MAV_CMD_REQUEST_MESSAGE`` for ``CAMERA_INFORMATION`` (flags ``HAS_TRACKING_POINT`` and
  ``HAS_TRACKING_RECTANGLE``, the stream's resolution) and for the tracking status;
* ``MAV_CMD_CAMERA_TRACK_RECTANGLE`` and ``MAV_CMD_CAMERA_TRACK_POINT`` start a session of the
  service on the stream, or re-initialise the camera's session; coordinates are normalised to
  [0, 1] and converted with the size of the stream's latest frame (a point and its radius
  become a square box); ``MAV_CMD_CAMERA_STOP_TRACKING`` stops it;
* every command is acknowledged (``COMMAND_ACK``): accepted; denied when the stream has no
  frame yet or the box is unusable; failed when the service refuses; a reason goes along in a
  ``STATUSTEXT``;
* ``CAMERA_TRACKING_IMAGE_STATUS`` is streamed at the interval the station asks for
  (``MAV_CMD_SET_MESSAGE_INTERVAL``), mapped from the track state: tracking → ACTIVE,
  coasting → ACTIVE | COASTING, lost → ERROR, no session → IDLE;
* a stale session is never ACTIVE: when the service says its stream stopped (a ``stale``
  result) or no result at all came for ``stale_after_s`` (the service or its worker gone),
  the status is ERROR with NaN coordinates and target data NONE (the spec's "NAN if
  unknown": an autopilot must not follow the last box), with a ``STATUSTEXT`` when it
  starts and when results resume; the status goes out at once on either change (when the
  notice or the result arrives, or the timeout passes), not at its next interval;
* a station's heartbeats are watched: when they stop for ``link_timeout_s`` the link is
  reported lost (the sessions go on, as a camera keeps tracking without its station), and
  found again when they come back.

Hardened like the service, for a link anyone in radio range (or on the network) can reach:

* the table of recent commands (for retransmissions) keeps ``DONE_KEPT_S`` seconds and at
  most ``DONE_MAX`` entries, whatever is sent;
* listening (``udpin``), it answers at most ``MAX_PEERS`` addresses: those that sent a
  station heartbeat first, then the most recently heard, each forgotten ``link_timeout_s``
  after its last packet (pymavlink would otherwise send every message to every source
  port it ever heard);
* a frame's size is read from its header (JPEG / PNG) or its declaration, never by
  decoding it, and a size above ``max_pixels`` is refused;
* with a signing key (``--signing-key``), every message sent is signed (MAVLink 2 signing)
  and only correctly signed messages are accepted: a station must then hold the key to
  command the camera. Rejected messages are counted (``unsigned``).

MAVLink 2 only (these message ids need it): ``MAVLINK20=1`` is set before pymavlink loads.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import logging
import math
import os
import queue
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil

from arcf.client import ServiceError, TrackingClient
from arcf.client.media.encodings import codec_of
from arcf.schemas import ErrorCode, Frame, Result, ResultStatus, TrackState

from ._command import (
    add_service_arguments,
    add_session_arguments,
    check_preset,
    connect,
    serve_counts,
)
from .gimbal import FollowSettings, GimbalFollower, GimbalTarget
from .tap import DEFAULT_VIDEO_KEY, StreamTap, TapFrame

if TYPE_CHECKING:  # PyAV loads with a video stream's first unit, not with the adapter
    from arcf.client.media.video import PictureSize

log = logging.getLogger(__name__)
mav = mavutil.mavlink

#: MAV_COMP_ID_CAMERA: the first of the six camera component ids (100-105)
FIRST_CAMERA_COMPONENT = mav.MAV_COMP_ID_CAMERA
#: commands this component acts on
TRACK_COMMANDS = (mav.MAV_CMD_CAMERA_TRACK_POINT, mav.MAV_CMD_CAMERA_TRACK_RECTANGLE,
                  mav.MAV_CMD_CAMERA_STOP_TRACKING)
#: fastest status stream a station may ask for (100 Hz)
MIN_INTERVAL_S = 0.01
#: CAMERA_TRACKING_TARGET_DATA_NONE, "no target data" (a bitmask enum: no bit set), which
#: pymavlink's generated constants leave out
TARGET_DATA_NONE = getattr(mav, "CAMERA_TRACKING_TARGET_DATA_NONE", 0)


@dataclass(frozen=True)
class VideoStream:
    """The video a station should show for a camera, as ``VIDEO_STREAM_INFORMATION`` says it:
    ``kind`` is a ``VIDEO_STREAM_TYPE`` and ``uri`` what the station opens (an RTSP URI) or
    the UDP port it listens on (RTP, MPEG-TS), as the message's definition has it."""

    kind: int
    uri: str

    @classmethod
    def parse(cls, text: str) -> VideoStream:
        """``rtsp://HOST[:PORT]/PATH`` (the station connects), ``rtp://[HOST]:PORT`` (RTP over
        UDP: the station listens on PORT, QGroundControl's 5600 by convention) or
        ``udp://[HOST]:PORT`` (MPEG-TS over UDP), as ``arcf-ingest`` names sources."""
        if text.startswith(("rtsp://", "rtsps://")):
            uri, kind = text, mav.VIDEO_STREAM_TYPE_RTSP
        else:
            scheme, _, rest = text.partition("://")
            kinds = {"rtp": mav.VIDEO_STREAM_TYPE_RTPUDP, "udp": mav.VIDEO_STREAM_TYPE_MPEG_TS}
            port = rest.rpartition(":")[2].strip("/")
            if scheme not in kinds or not port.isdigit() or not 0 < int(port) < 65536:
                raise ValueError(f"a video stream is rtsp://HOST/PATH, rtp://[HOST]:PORT or "
                                 f"udp://[HOST]:PORT, got {text!r}")
            uri, kind = port, kinds[scheme]
        if len(uri.encode()) > 160:
            raise ValueError("a video stream URI holds at most 160 bytes")
        return cls(kind, uri)


@dataclass(frozen=True)
class CameraConfig:
    """One MAVLink camera: the service's stream it shows, its component id and the video a
    station should show for it (None: the camera advertises no video)."""

    stream_id: str
    component_id: int
    video: VideoStream | None = None
    #: the gimbal its session steers to keep the target centred (None: none)
    follow: GimbalTarget | None = None


@dataclass
class _Camera:
    config: CameraConfig
    encoder: Any  # a pymavlink MAVLink encoder sending as this component
    number: int  # 1-based, as the track commands' "camera id" parameter counts cameras
    last_frame: TapFrame | None = None
    #: the picture size of a video stream, read from its keyframes when needed
    video_size: PictureSize | None = None
    #: monotonic time of the last frame
    frame_at: float = 0.0
    #: turns the session's boxes into gimbal rate commands (``CameraConfig.follow``)
    follower: GimbalFollower | None = None
    session_id: str | None = None
    mode: int = mav.CAMERA_TRACKING_MODE_NONE
    result: Result | None = None
    status_interval_s: float = 0.1
    next_status: float = 0.0
    #: monotonic time of the session's last result, or of its start / reinit
    heard_at: float = 0.0
    #: what the station was last told: stale (True) or not
    stale: bool = False
    #: what the station was last told makes the status ERROR besides staleness: an error
    #: result's code (``error:<code>``), a lost target (None: nothing)
    trouble: str | None = None
    #: the picture size the last CAMERA_INFORMATION carried (None: none sent yet)
    told_size: tuple[int, int] | None = None


@dataclass
class Box:
    """A box in the frame's 1-based pixel coordinates (the service's convention)."""

    x: float
    y: float
    w: float
    h: float


class Denied(Exception):
    """A command that cannot be carried out as given (``MAV_RESULT_DENIED``)."""


def frame_size(frame: Frame | TapFrame, max_pixels: int = 4096 * 2160,
               video: PictureSize | None = None) -> tuple[int, int]:
    """(width, height) of a stream's frame: declared, read from its JPEG / PNG header, or
    for video from the stream's latest keyframe (``video``, which decodes it once per set of
    parameter sets). Raises ``ValueError`` for a size that cannot be read or is above
    ``max_pixels`` (the service's default limit)."""
    codec = codec_of(frame.encoding)
    encoding = codec.encoding.value
    if frame.width and frame.height:
        size = (frame.width, frame.height)
    else:
        read = None
        if codec.read_size is not None:
            read = codec.read_size(frame.payload)
        elif codec.is_video and video is not None:
            read = video.read()
            if read is None:
                raise ValueError(f"no {encoding} keyframe with its parameter sets yet")
        if read is None:
            raise ValueError(f"no size in a {encoding} frame's header")
        size = read
    if size[0] * size[1] > max_pixels:
        raise ValueError(f"{size[0]}x{size[1]} is above {max_pixels} pixels")
    return size


def rectangle_box(top_x: float, top_y: float, bottom_x: float, bottom_y: float,
                  size: tuple[int, int]) -> Box:
    """``MAV_CMD_CAMERA_TRACK_RECTANGLE``'s normalised corners (0 = left/top) as a box."""
    values = (top_x, top_y, bottom_x, bottom_y)
    if not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in values):
        raise Denied("rectangle corners must be within [0, 1]")
    if bottom_x <= top_x or bottom_y <= top_y:
        raise Denied("bottom-right must be below and right of top-left")
    w, h = size
    box = Box(top_x * w + 1.0, top_y * h + 1.0, (bottom_x - top_x) * w, (bottom_y - top_y) * h)
    if box.w < 2 or box.h < 2:
        raise Denied(f"rectangle is {box.w:.1f}x{box.h:.1f} px, below 2x2")
    return box


def point_box(x: float, y: float, radius: float, size: tuple[int, int]) -> Box:
    """``MAV_CMD_CAMERA_TRACK_POINT``: the square of side 2 radius (a share of the image
    width) around the point, cut to the frame."""
    if not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in (x, y, radius)):
        raise Denied("point and radius must be within [0, 1]")
    w, h = size
    half = radius * w
    if half < 1:
        raise Denied(f"radius {radius:g} is {half:.1f} px, below 1")
    cx, cy = x * w, y * h
    left, top = max(cx - half, 0.0), max(cy - half, 0.0)
    right, bottom = min(cx + half, float(w)), min(cy + half, float(h))
    if right - left < 2 or bottom - top < 2:
        raise Denied("the point's square is outside the frame")
    return Box(left + 1.0, top + 1.0, right - left, bottom - top)


def tracking_status(result: Result | None) -> int:
    """``CAMERA_TRACKING_STATUS_FLAGS`` of a camera whose latest result is ``result``.

    A ``stale`` result (the stream's frames stopped) is ERROR, "tracking in error state":
    the camera was asked to track and cannot. Not IDLE, which says nobody asked (the session
    goes on and resumes with the frames), nor COASTING, which says the target is being
    predicted (nothing is). The same flag as a lost target: the station tells them apart by
    the coordinates, NaN for a stale session, and by the ``STATUSTEXT``."""
    if result is None:
        return mav.CAMERA_TRACKING_STATUS_FLAGS_IDLE
    if result.status in (ResultStatus.ERROR, ResultStatus.STALE) or result.track_state is None:
        return mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR
    if result.track_state is TrackState.TRACKING:
        return mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
    if result.track_state is TrackState.COASTING:
        return (mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
                | mav.CAMERA_TRACKING_STATUS_FLAGS_COASTING)
    return mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR


def whole(value: float) -> int | None:
    """A command parameter that must be a whole number (a message id, a camera id), or None
    when it is not one (NaN, infinite, fractional): such a command is refused, never trusted."""
    if not math.isfinite(value) or value != int(value):
        return None
    return int(value)


#: how long a completed command's result is kept for its retransmissions (COMMAND_LONG with
#: ``confirmation`` > 0), which get the same acknowledgement instead of a second execution,
#: and the most results kept (the oldest go first): a station retransmits its last command,
#: not the 257th before it
DONE_KEPT_S = 5.0
DONE_MAX = 256
#: the most addresses a listening (udpin) link sends to
MAX_PEERS = 8
#: MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION / _STATUS (deprecated for REQUEST_MESSAGE, still
#: sent by older stations) -> the message each asks for
_VIDEO_REQUESTS = {getattr(mav, "MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION", 2504):
                   mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
                   getattr(mav, "MAV_CMD_REQUEST_VIDEO_STREAM_STATUS", 2505):
                   mav.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS}
#: a frame encoding -> VIDEO_STREAM_ENCODING
_VIDEO_ENCODINGS = {"h264": getattr(mav, "VIDEO_STREAM_ENCODING_H264", 1),
                    "h265": getattr(mav, "VIDEO_STREAM_ENCODING_H265", 2)}


def _padded(text: str, size: int) -> list[int]:
    raw = text.encode()[:size]
    return list(raw) + [0] * (size - len(raw))


class MavlinkCameras:
    """One MAVLink camera component per stream, in front of a tracking service.

    ``client`` talks to the service; ``connection`` is a pymavlink connection string
    (``udpin:0.0.0.0:14540``, ``udpout:192.168.1.10:14550``, ``tcp:127.0.0.1:5760``,
    ``/dev/ttyUSB0,57600``...). Call :meth:`run` (blocking, until :meth:`close` or the event
    is set) or :meth:`start` (in a thread). ``counts`` tallies what happened (commands by
    result, link losses, malformed packets) for tests and logs.
    """

    def __init__(self, client: TrackingClient, connection: str,
                 cameras: Sequence[CameraConfig], *, system_id: int = 1,
                 preset: str = "arcf-hc", overrides: Mapping[str, Any] | None = None,
                 status_interval_s: float = 0.1, heartbeat_s: float = 1.0,
                 link_timeout_s: float = 5.0, stale_after_s: float = 0.8,
                 signing_key: bytes | None = None, max_pixels: int = 4096 * 2160,
                 video_key: str | None = DEFAULT_VIDEO_KEY,
                 follow_clock: Callable[[], float] = time.monotonic) -> None:
        """``stale_after_s``: a session with no result for this long is reported stale
        (ERROR, no box), as the service reports a stream without frames; the service's own
        setting of the same name is the right value (0: only the service's notices).
        ``signing_key``: 32 bytes of MAVLink 2 signing secret (sign everything, accept only
        signed messages). ``max_pixels``: the largest frame a command is carried out on.
        ``video_key``: the service's key of CDR ``CompressedVideo`` streams (None: none), whose
        units the camera shows as well as the service's own frames. ``follow_clock``: the
        follow controllers' time, seconds (a simulation closes the loop in its own time)."""
        if signing_key is not None and len(signing_key) != 32:
            raise ValueError(f"a MAVLink signing key is 32 bytes, got {len(signing_key)}")
        if not cameras:
            raise ValueError("at least one camera (stream) is needed")
        if not (stale_after_s >= 0 and math.isfinite(stale_after_s)):
            raise ValueError(f"stale_after_s must be a finite number >= 0, got {stale_after_s}")
        ids = [c.component_id for c in cameras]
        if len(set(ids)) != len(ids) or not all(1 <= i <= 255 for i in ids):
            raise ValueError(f"component ids must be distinct, in 1..255: {ids}")
        self.client = client
        self.preset = preset
        self.overrides = dict(overrides or {})
        self.heartbeat_s = heartbeat_s
        self.link_timeout_s = link_timeout_s
        self.stale_after_s = stale_after_s
        self.counts: Counter[str] = Counter()
        self.max_pixels = max_pixels
        self.follow_clock = follow_clock
        self.conn = mavutil.mavlink_connection(connection, source_system=system_id,
                                               source_component=ids[0], autoreconnect=True,
                                               udp_timeout=link_timeout_s)
        #: listening: addresses that sent a station heartbeat (kept first), in arrival order
        self._stations: dict[Any, None] = {}
        self._send_lock = threading.Lock()
        self._state_lock = threading.Lock()
        #: one thread at a time decides a camera's stale / not stale change (``_announce``)
        self._announce_lock = threading.Lock()
        self._t0 = time.monotonic()
        self.cameras = [
            _Camera(c, mav.MAVLink(self.conn, srcSystem=system_id, srcComponent=c.component_id),
                    number=i + 1, status_interval_s=status_interval_s)
            for i, c in enumerate(cameras)]
        for cam in self.cameras:
            f = cam.config.follow
            if f is not None:
                cam.follower = GimbalFollower(
                    functools.partial(self._send, cam), (system_id, cam.config.component_id),
                    (f.system, f.component), gimbal_device_id=f.device_id,
                    settings=f.settings, max_command_hz=f.max_command_hz)
        self.conn.mav.robust_parsing = True  # bad bytes come back as BAD_DATA, counted
        self.signed = signing_key is not None
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=True)
            for cam in self.cameras:  # each camera's encoder signs what it sends
                cam.encoder.signing = self.conn.mav.signing
        #: frame size per stream, read at the last track command (for frames that do not
        #: declare theirs)
        self._sizes: dict[str, tuple[int, int]] = {}
        self._by_component = {c.config.component_id: c for c in self.cameras}
        self._commands: queue.Queue[tuple[_Camera, Any] | None] = queue.Queue(maxsize=64)
        self._pending: set[tuple[int, int, tuple[str, ...]]] = set()
        self._done: dict[tuple[int, int, tuple[str, ...]], tuple[float, int]] = {}
        self.status_interval_s = status_interval_s
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._next_heartbeat = 0.0
        self._text_id = 0
        self._last_station: float | None = None
        self.link_up = False
        # last: their callbacks may run at once
        self._taps = [StreamTap(client, cam.config.stream_id, self._frame_seen(cam),
                                self._result_seen(cam), video_key) for cam in self.cameras]

    # ------------------------------------------------------------------ service side
    def _frame_seen(self, cam: _Camera) -> Any:
        def seen(frame: TapFrame) -> None:
            size = None
            if frame.is_video:  # its size is in its keyframes: kept for a command's need
                codec = codec_of(frame.encoding)
                size = cam.video_size
                if size is None or size.codec != codec.ffmpeg:
                    size = codec.size_reader(self.max_pixels)
                size.feed(frame.payload)
            with self._state_lock:
                cam.last_frame, cam.frame_at = frame, time.monotonic()
                if size is not None:
                    cam.video_size = size
        return seen

    def _result_seen(self, cam: _Camera) -> Any:
        def seen(result: Result) -> None:
            with self._state_lock:
                if result.session_id != cam.session_id:
                    return  # another station's session on the same stream
                stopped = result.status == ResultStatus.STOPPED
                # interrupted, not ended (its instance stopped): kept, shown paused, until it
                # resumes there or elsewhere under the same id
                interrupted = stopped and result.code == ErrorCode.INTERRUPTED
                if stopped and not interrupted:
                    cam.session_id, cam.result = None, None
                    cam.mode = mav.CAMERA_TRACKING_MODE_NONE
                    if result.code is not None:  # the service ended it (a stop says nothing)
                        self._statustext(cam, f"tracking ended ({result.code.value}): "
                                              f"{result.message or 'no reason given'}")
                elif interrupted:
                    cam.result = result
                else:
                    cam.result, cam.heard_at = result, time.monotonic()
                    self._tell_trouble(cam, result)
                frame = cam.last_frame
            if cam.follower is not None:  # the gimbal follows a box, or is let go
                size = ((frame.width, frame.height) if frame is not None and frame.width
                        and frame.height else self._sizes.get(cam.config.stream_id))
                cam.follower.on_result(result, size, self.follow_clock())
            if not stopped or interrupted:
                # a stale notice, an interruption, or the first result after one: the
                # station hears it now
                self._announce(cam, time.monotonic())
        return seen

    def _tell_trouble(self, cam: _Camera, result: Result) -> None:
        """A result that makes the status ERROR for a reason of its frame (an error result:
        a picture that could not be decoded, a video waiting for its keyframe, a box that
        does not fit; a lost target) is told in a STATUSTEXT once, when it starts, and its
        end once; a stale session is told by :meth:`_announce`. Call with the state lock."""
        # the kind of trouble, told once: an error's code (its message names the frame, and
        # a video waiting for its keyframe gives one a frame), or a lost target
        text: str | None = None
        if result.status == ResultStatus.ERROR:
            code = result.code.value if result.code is not None else "error"
            trouble: str | None = f"error:{code}"
            text = f"tracking error: {result.message or code}"
        elif result.track_state == TrackState.LOST:
            trouble = text = "target lost"
        elif result.status == ResultStatus.STALE:
            return  # told as stale
        else:
            trouble = None
        if trouble == cam.trouble:
            return
        if text is not None:
            self._statustext(cam, text)
        elif cam.trouble is not None:
            self._statustext(cam, "target tracked again" if cam.trouble == "target lost"
                             else "tracking again", mav.MAV_SEVERITY_INFO)
        cam.trouble = trouble

    def _linked(self) -> bool | None:
        """Whether the service client has any Zenoh link (a router or a peer); None when it
        cannot tell (a stand-in client)."""
        try:
            info = self.client.session.info
            return any(info.routers_zid()) or any(info.peers_zid())
        except AttributeError:
            return None

    def stale(self, cam: _Camera, now: float) -> str | None:
        """Why ``cam``'s session has no current box (None: it has one, or no session): the
        service said its stream stopped, or that it interrupted the session (its instance
        stopped), or no result came for ``stale_after_s``."""
        with self._state_lock:
            session, result, heard_at = cam.session_id, cam.result, cam.heard_at
            frame_at = cam.frame_at
        if session is None:
            return None
        if result is not None and result.status == ResultStatus.STALE:
            return "no frames" if not result.message else result.message
        if result is not None and result.status == ResultStatus.STOPPED:  # interrupted
            return ("the tracking service stopped (a restart or a fail-over); the track "
                    "resumes when it is back")
        if self.stale_after_s and now - heard_at > self.stale_after_s:
            # whose silence: frames reach this camera through the service's Zenoh network
            if self._linked() is False:
                return (f"no link to the tracking service's network for "
                        f"{now - heard_at:.1f} s (its router is gone or out of reach)")
            if now - frame_at > self.stale_after_s:  # the frames stopped too: the camera's
                return f"no frame from the camera for {now - frame_at:.1f} s"
            return f"no result from the tracking service for {now - heard_at:.1f} s"
        return None

    # ------------------------------------------------------------------ running
    def start(self) -> MavlinkCameras:
        """Run in background threads; :meth:`close` stops them."""
        self._threads = [threading.Thread(target=self.run, name="mavlink-io", daemon=True)]
        self._threads[0].start()
        return self

    def run(self) -> None:
        """Receive and answer until :meth:`close`: the I/O loop (heartbeats, status, fast
        requests) here, the commands that wait for the service in a second thread."""
        worker = threading.Thread(target=self._command_loop, name="mavlink-commands",
                                  daemon=True)
        worker.start()
        try:
            while not self._stop.is_set():
                try:
                    # short waits: the status ticks below run between packets
                    msg = self.conn.recv_match(blocking=True, timeout=0.005)
                except (OSError, ValueError) as exc:  # a broken serial line, a bad packet
                    self.counts["receive_errors"] += 1
                    log.debug("mavlink receive: %s", exc)
                    msg = None
                try:
                    if msg is not None:
                        self._receive(msg)
                    self._tick(time.monotonic())
                except Exception:  # one packet, one bug: counted, logged, never fatal
                    self.counts["internal_errors"] += 1
                    log.exception("mavlink: packet %s not handled", msg)
        finally:
            self._commands.put(None)
            worker.join(timeout=5)

    @property
    def alive(self) -> bool:
        """The I/O loop runs (started with :meth:`start` and not closed)."""
        return bool(self._threads) and self._threads[0].is_alive()

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5)
        for tap in self._taps:
            tap.close()
        self.conn.close()

    # ------------------------------------------------------------------ sending
    def _send(self, cam: _Camera, message: Any) -> None:
        with self._send_lock:
            try:
                cam.encoder.send(message)
            except OSError as exc:  # no peer yet on udpin, a closed socket
                self.counts["send_errors"] += 1
                log.debug("mavlink send: %s", exc)

    def _statustext(self, cam: _Camera, text: str,
                    severity: int = mav.MAV_SEVERITY_WARNING) -> None:
        """A reason for the station's operator. A STATUSTEXT holds 50 bytes; a longer text
        goes in chunks sharing an ``id`` (MAVLink 2), which stations join."""
        raw = text.encode()[:500]
        if len(raw) <= 50:
            self._send(cam, mav.MAVLink_statustext_message(severity, raw))
            return
        self._text_id = self._text_id % 65535 + 1
        for seq, start in enumerate(range(0, len(raw), 50)):
            self._send(cam, mav.MAVLink_statustext_message(severity, raw[start:start + 50],
                                                           self._text_id, seq))

    def _ack(self, cam: _Camera, msg: Any, result: int, reason: str | None = None) -> None:
        self.counts[f"ack_{result}"] += 1
        if reason:
            self._statustext(cam, reason)  # the component says which camera
        self._send(cam, mav.MAVLink_command_ack_message(
            msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _tick(self, now: float) -> None:
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + self.heartbeat_s
            for cam in self.cameras:
                self._send(cam, mav.MAVLink_heartbeat_message(
                    mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                    mav.MAV_STATE_ACTIVE, 3))
                # the stations that asked hear of a new picture size (the first frame, a
                # camera restarted at another resolution) without asking again
                if cam.told_size is not None and (self._size(cam) or (0, 0)) != cam.told_size:
                    self._inform(cam)
        if (self.link_up and self._last_station is not None
                and now - self._last_station > self.link_timeout_s):
            self.link_up = False
            self.counts["link_lost"] += 1
            log.warning("mavlink: no station heartbeat for %.1f s: link lost (tracking "
                        "goes on)", now - self._last_station)
        for cam in self.cameras:
            self._announce(cam, now)  # the adapter's own timeout passed, or a session ended
            if cam.follower is not None:
                cam.follower.tick(self.follow_clock())  # a silent session: let go
            if cam.status_interval_s > 0 and now >= cam.next_status:
                cam.next_status = max(cam.next_status + cam.status_interval_s, now - 1.0)
                self._send(cam, self._status(cam, now))

    def _announce(self, cam: _Camera, now: float) -> None:
        """Tell the station when ``cam``'s session goes stale or stops being stale: once per
        change, a ``STATUSTEXT`` saying why and the status at once, not at its next interval
        (unless the station turned the status off). Called by the I/O loop's tick (the
        adapter's own timeout, a session's end) and by each result as it arrives (the
        service's stale notice, the first result about a frame after it), whichever sees
        the change first."""
        with self._announce_lock:
            why = self.stale(cam, now)
            if (why is not None) == cam.stale:  # no change: nothing to tell
                return
            cam.stale = why is not None
            if cam.stale:
                self.counts["stale"] += 1
                self._statustext(cam, f"tracking stale: {why}")
                log.warning("mavlink: camera %d stale: %s", cam.config.component_id, why)
            elif cam.session_id is not None:  # results again (not: the session ended)
                self.counts["stale_ended"] += 1
                self._statustext(cam, "tracking resumed", mav.MAV_SEVERITY_INFO)
            if cam.status_interval_s > 0:
                self._send(cam, self._status(cam, now))

    def _status(self, cam: _Camera, now: float | None = None) -> Any:
        """The camera's ``CAMERA_TRACKING_IMAGE_STATUS`` at ``now`` (monotonic; default:
        the clock's)."""
        stale = self.stale(cam, time.monotonic() if now is None else now) is not None
        with self._state_lock:
            session, result, mode, frame = cam.session_id, cam.result, cam.mode, cam.last_frame
        nan = float("nan")
        coords = [nan] * 7  # point_x, point_y, radius, rec_top_x/y, rec_bottom_x/y
        if stale:  # no current box: NaN, no target data, never ACTIVE
            return mav.MAVLink_camera_tracking_image_status_message(
                mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR, mode,
                TARGET_DATA_NONE, *coords, 0)
        size = (frame.width, frame.height) if frame and frame.width and frame.height else None
        size = size or self._sizes.get(cam.config.stream_id)
        boxed = False
        if session and result is not None and size and all(map(math.isfinite, result.box)):
            boxed = True
            x, y, w, h = result.box
            fw, fh = size
            left, top = (x - 1.0) / fw, (y - 1.0) / fh
            coords = [left + w / fw / 2, top + h / fh / 2, w / fw / 2,
                      left, top, left + w / fw, top + h / fh]
        if session is None:
            return mav.MAVLink_camera_tracking_image_status_message(
                mav.CAMERA_TRACKING_STATUS_FLAGS_IDLE, mav.CAMERA_TRACKING_MODE_NONE, 0,
                *coords, 0)
        # target data only with a box: not before the session's first result, nor with a
        # notice that carries none (NaN: the spec's "unknown")
        return mav.MAVLink_camera_tracking_image_status_message(
            tracking_status(result) if result is not None
            else mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE,  # started, first result on its way
            mode, mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS if boxed else TARGET_DATA_NONE,
            *coords, 0)

    def _inform(self, cam: _Camera) -> None:
        """``CAMERA_INFORMATION``, and with a video stream its ``VIDEO_STREAM_INFORMATION``
        (MAVSDK asks for that only every 20 s, and shows no video until then)."""
        cam.told_size = self._size(cam) or (0, 0)
        self._send(cam, self._information(cam))
        if cam.config.video is not None:
            self._send(cam, self._video_information(cam))

    def _information(self, cam: _Camera) -> Any:
        w, h = self._size(cam) or (0, 0)  # unreadable or too large: 0 x 0
        nan = float("nan")
        flags = (mav.CAMERA_CAP_FLAGS_HAS_TRACKING_POINT
                 | mav.CAMERA_CAP_FLAGS_HAS_TRACKING_RECTANGLE)
        if cam.config.video is not None:
            flags |= mav.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        return mav.MAVLink_camera_information_message(
            int(1e3 * (time.monotonic() - self._t0)) & 0xFFFFFFFF, _padded("arcf", 32),
            _padded(f"ARCF tracker {cam.config.stream_id}", 32), 0, nan, nan, nan, w, h, 0,
            flags, 0, b"", 0, 0)

    def _size(self, cam: _Camera) -> tuple[int, int] | None:
        """The stream's picture size: its latest frame's (declared, from its header, or from
        its video's keyframe), else the last one read; None if none could be read."""
        with self._state_lock:
            frame, video = cam.last_frame, cam.video_size
        stream = cam.config.stream_id
        if frame is not None:
            with contextlib.suppress(ValueError):
                self._sizes[stream] = frame_size(frame, self.max_pixels, video)
        return self._sizes.get(stream)

    def _video_running(self, cam: _Camera) -> bool:
        with self._state_lock:
            return cam.last_frame is not None and time.monotonic() - cam.frame_at < max(
                self.stale_after_s, 1.0)

    def _video_information(self, cam: _Camera) -> Any:
        """``VIDEO_STREAM_INFORMATION`` of the camera's one stream (id 1)."""
        video = cam.config.video
        assert video is not None
        w, h = self._size(cam) or (0, 0)
        with self._state_lock:
            encoding = cam.last_frame.encoding if cam.last_frame is not None else None
        return mav.MAVLink_video_stream_information_message(
            1, 1, video.kind,
            mav.VIDEO_STREAM_STATUS_FLAGS_RUNNING if self._video_running(cam) else 0,
            0.0, w, h, 0, 0, 0, f"arcf {cam.config.stream_id}".encode()[:32],
            video.uri.encode(), _VIDEO_ENCODINGS.get(encoding or "", 0))

    def _video_status(self, cam: _Camera) -> Any:
        w, h = self._size(cam) or (0, 0)
        return mav.MAVLink_video_stream_status_message(
            1, mav.VIDEO_STREAM_STATUS_FLAGS_RUNNING if self._video_running(cam) else 0,
            0.0, w, h, 0, 0, 0)

    # ------------------------------------------------------------------ receiving
    def _trim_peers(self, station: bool) -> None:
        """A listening link's peers: the sender of the last packet, if it was a station's
        heartbeat, joins the stations; beyond ``MAX_PEERS`` addresses, the least recently
        heard that are not stations are forgotten. A station keeps its place while it is
        heard (``link_timeout_s``); a new one gets a free or a quiet station's place. pymavlink
        keeps the addresses (``clients``, with when each was last heard) but not which one
        sent a message: that is the one heard last, as each message comes from the datagram
        just read."""
        clients = getattr(self.conn, "clients", None)  # pymavlink's mavudp, listening
        alive = getattr(self.conn, "clients_last_alive", None)
        if not isinstance(clients, set) or not isinstance(alive, dict):
            return
        if station and alive:  # the sender of the last datagram: the one heard last
            sender = max(alive, key=alive.__getitem__)
            if sender not in self._stations:
                # a newcomer takes the place of a station gone quiet (link_timeout_s), never
                # of one still heard: a flood of forged heartbeats cannot push a live
                # station out (signing, --signing-key, keeps forgeries out altogether)
                now = time.time()
                quiet = [a for a in self._stations
                         if now - alive.get(a, 0.0) > self.link_timeout_s]
                for address in quiet[:max(0, len(self._stations) + 1 - MAX_PEERS)]:
                    del self._stations[address]
                if len(self._stations) < MAX_PEERS:
                    self._stations[sender] = None
        if len(clients) <= MAX_PEERS:
            return
        keep = sorted(clients, key=lambda a: (a in self._stations, alive.get(a, 0.0)),
                      reverse=True)[:MAX_PEERS]
        for address in clients - set(keep):
            clients.discard(address)
            alive.pop(address, None)
            self.counts["peers_forgotten"] += 1

    def _receive(self, msg: Any) -> None:
        kind = msg.get_type()
        self._trim_peers(kind == "HEARTBEAT" and getattr(msg, "type", None) != mav.MAV_TYPE_CAMERA)
        if kind == "BAD_DATA":
            if self.signed and "signature" in str(getattr(msg, "reason", "")):
                self.counts["unsigned"] += 1
            else:
                self.counts["malformed"] += 1
            return
        if msg.get_srcSystem() == self.conn.source_system and \
                msg.get_srcComponent() in self._by_component:
            return  # our own echo (a loopback or broadcast link)
        if kind == "HEARTBEAT":
            if msg.type != mav.MAV_TYPE_CAMERA:
                self._last_station = time.monotonic()
                if not self.link_up:
                    self.link_up = True
                    self.counts["link_up"] += 1
                    log.info("mavlink: station heartbeat from %d/%d", msg.get_srcSystem(),
                             msg.get_srcComponent())
            return
        if kind not in ("COMMAND_LONG", "COMMAND_INT"):
            return
        if msg.target_system not in (0, self.conn.source_system):
            return
        for cam in self._addressed(msg):
            self.counts["commands"] += 1
            self._command(cam, msg)

    def _addressed(self, msg: Any) -> list[_Camera]:
        """The cameras a command is for: the one it names by component id; on a broadcast
        (component 0), those its camera-id parameter selects: 0 all, a camera's component
        id (MAVLink's 7-255), or its position 1..N among this endpoint's cameras."""
        if msg.target_component in self._by_component:
            return [self._by_component[msg.target_component]]
        if msg.target_component != 0:
            return []
        raw = 0.0
        if msg.command == mav.MAV_CMD_CAMERA_TRACK_POINT:
            raw = msg.param4
        elif msg.command == mav.MAV_CMD_CAMERA_TRACK_RECTANGLE:  # COMMAND_INT: its x
            raw = msg.param5 if hasattr(msg, "param5") else float(msg.x)
        elif msg.command == mav.MAV_CMD_CAMERA_STOP_TRACKING:
            raw = msg.param1
        camera_id = whole(raw)
        if camera_id is None:
            self.counts["bad_camera_id"] += 1
            return []  # not a camera id: addressed to no camera of ours
        return [c for c in self.cameras
                if camera_id in (0, c.number, c.config.component_id)]

    def _command(self, cam: _Camera, msg: Any) -> None:
        cmd = msg.command
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            interval_us = msg.param2
            if (whole(msg.param1) != mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS
                    or not math.isfinite(interval_us) or interval_us < -1):
                self._ack(cam, msg, mav.MAV_RESULT_DENIED)
                return
            if interval_us == -1:
                cam.status_interval_s = 0.0  # disabled
            elif interval_us == 0:
                cam.status_interval_s = self.status_interval_s  # the default rate
            else:
                cam.status_interval_s = max(interval_us / 1e6, MIN_INTERVAL_S)
            cam.next_status = time.monotonic()
            self._ack(cam, msg, mav.MAV_RESULT_ACCEPTED)
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE or cmd == getattr(
                mav, "MAV_CMD_REQUEST_CAMERA_INFORMATION", -1):
            wanted = (mav.MAVLINK_MSG_ID_CAMERA_INFORMATION
                      if cmd != mav.MAV_CMD_REQUEST_MESSAGE else whole(msg.param1))
            if wanted == mav.MAVLINK_MSG_ID_CAMERA_INFORMATION:
                self._ack(cam, msg, mav.MAV_RESULT_ACCEPTED)
                self._inform(cam)
            elif wanted == mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS:
                self._ack(cam, msg, mav.MAV_RESULT_ACCEPTED)
                self._send(cam, self._status(cam))
            elif wanted in (mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
                            mav.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS):
                self._video_request(cam, msg, wanted, msg.param2)
            else:
                self._ack(cam, msg, mav.MAV_RESULT_DENIED)
        elif cmd in _VIDEO_REQUESTS:  # the commands REQUEST_MESSAGE replaced
            self._video_request(cam, msg, _VIDEO_REQUESTS[cmd], msg.param1)
        elif cmd in TRACK_COMMANDS:
            key = self._key(cam, msg)
            if key in self._pending:
                return  # a retransmission of a command still being carried out
            done = self._done.get(key)
            # a retransmission (confirmation > 0) of a command done: its ack got lost?
            if (getattr(msg, "confirmation", 0) > 0 and done is not None
                    and time.monotonic() - done[0] < DONE_KEPT_S):
                self.counts["retransmissions"] += 1
                self._ack(cam, msg, done[1])
                return
            try:
                self._commands.put_nowait((cam, msg))
                self._pending.add(key)
            except queue.Full:
                self._ack(cam, msg, mav.MAV_RESULT_TEMPORARILY_REJECTED, "busy")
        else:
            self._ack(cam, msg, mav.MAV_RESULT_UNSUPPORTED)

    def _video_request(self, cam: _Camera, msg: Any, wanted: int, stream_id: float) -> None:
        """``VIDEO_STREAM_INFORMATION`` or ``_STATUS`` of stream ``stream_id`` (0 or NaN: all,
        NaN being what MAVSDK sends; the camera has one, id 1): denied, with the reason, when
        the camera advertises none."""
        if cam.config.video is None:
            self._ack(cam, msg, mav.MAV_RESULT_DENIED,
                      "no video stream configured for this camera (arcf-mavlink --video)")
        elif not math.isnan(stream_id) and whole(stream_id) not in (0, 1):
            self._ack(cam, msg, mav.MAV_RESULT_DENIED, f"no video stream {stream_id:g}")
        else:
            self._ack(cam, msg, mav.MAV_RESULT_ACCEPTED)
            self._send(cam, self._video_information(cam)
                       if wanted == mav.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION
                       else self._video_status(cam))

    # ------------------------------------------------------------------ track commands
    def _command_loop(self) -> None:
        while True:
            item = self._commands.get()
            if item is None:
                return
            cam, msg = item
            try:
                result, reason = self._track(cam, msg)
            except Exception as exc:  # never let one command stop the component
                log.exception("mavlink: command %d failed", msg.command)
                result, reason = mav.MAV_RESULT_FAILED, f"internal error: {exc}"
            key = self._key(cam, msg)
            self._pending.discard(key)
            self._remember(key, result)
            self._ack(cam, msg, result, reason)

    def _remember(self, key: tuple[int, int, tuple[str, ...]], result: int) -> None:
        """Keep a command's result for its retransmissions: at most ``DONE_MAX`` results, none
        older than ``DONE_KEPT_S`` (the table is in completion order, oldest first)."""
        now = time.monotonic()
        self._done.pop(key, None)
        self._done[key] = (now, result)
        while self._done:
            oldest = next(iter(self._done))
            if len(self._done) <= DONE_MAX and now - self._done[oldest][0] < DONE_KEPT_S:
                break
            del self._done[oldest]

    @staticmethod
    def _key(cam: _Camera, msg: Any) -> tuple[int, int, tuple[str, ...]]:
        """A command's identity for retransmissions (repr: NaN equals NaN)."""
        return (cam.config.component_id, msg.command,
                tuple(repr(v) for v in (msg.param1, msg.param2, msg.param3, msg.param4)))

    def _track(self, cam: _Camera, msg: Any) -> tuple[int, str | None]:
        """Carry out a track or stop command; (MAV_RESULT, reason for the station)."""
        stream = cam.config.stream_id
        if msg.command == mav.MAV_CMD_CAMERA_STOP_TRACKING:
            with self._state_lock:
                session, cam.session_id, cam.result = cam.session_id, None, None
                cam.mode = mav.CAMERA_TRACKING_MODE_NONE
            if session is not None:
                try:
                    self.client.stop(session)
                except (ServiceError, TimeoutError) as exc:
                    log.info("mavlink: stop of %s: %s", session, exc)  # it ended already
            return mav.MAV_RESULT_ACCEPTED, None
        with self._state_lock:
            frame, video, frame_at = cam.last_frame, cam.video_size, cam.frame_at
        if frame is None:
            return mav.MAV_RESULT_DENIED, "no frames yet on this stream"
        if not self._video_running(cam):  # the box would land on a picture long gone
            return (mav.MAV_RESULT_DENIED, f"the camera's stream is not delivering: no frame "
                    f"for {time.monotonic() - frame_at:.0f} s")
        try:
            size = frame_size(frame, self.max_pixels, video)
        except ValueError as exc:
            return mav.MAV_RESULT_DENIED, f"latest frame unusable: {exc}"
        # the service's own frames carry its numbering; CompressedVideo units are numbered
        # by the service as they arrive, which a listener cannot know: the box then applies
        # to the first picture the session sees
        frame_seq = frame.seq if frame.source == "frame" else None
        self._sizes[stream] = size
        try:
            if msg.command == mav.MAV_CMD_CAMERA_TRACK_RECTANGLE:
                box = rectangle_box(msg.param1, msg.param2, msg.param3, msg.param4, size)
                mode = mav.CAMERA_TRACKING_MODE_RECTANGLE
            else:
                box = point_box(msg.param1, msg.param2, msg.param3, size)
                mode = mav.CAMERA_TRACKING_MODE_POINT
        except Denied as exc:
            return mav.MAV_RESULT_DENIED, str(exc)
        xywh = (box.x, box.y, box.w, box.h)
        try:
            if cam.session_id is not None:
                try:
                    self.client.reinit(cam.session_id, xywh, frame_seq=frame_seq)
                    with self._state_lock:
                        cam.mode = mode
                        if cam.result is None:  # no result yet: its wait starts again
                            cam.heard_at = time.monotonic()
                    return mav.MAV_RESULT_ACCEPTED, None
                except ServiceError as exc:
                    if exc.code != ErrorCode.NO_SESSION.value:
                        raise
                    # the service ended it meanwhile: start a new one
            ack = self.client.start(stream, xywh, preset=self.preset,
                                    overrides=self.overrides, frame_seq=frame_seq)
        except ServiceError as exc:
            return mav.MAV_RESULT_FAILED, f"{exc.code}: {exc.error.message}"
        except TimeoutError:
            return mav.MAV_RESULT_FAILED, "the tracking service did not answer"
        with self._state_lock:
            cam.session_id, cam.result, cam.mode = ack.session_id, None, mode
            cam.heard_at = time.monotonic()  # the first result is on its way from here
        if cam.follower is not None:
            cam.follower.take_control()
        return mav.MAV_RESULT_ACCEPTED, None


# ---------------------------------------------------------------------------------- command
def _camera(text: str, index: int) -> CameraConfig:
    stream, _, comp = text.partition("=")
    return CameraConfig(stream, int(comp) if comp else FIRST_CAMERA_COMPONENT + index)


def _signing_key(text: str) -> bytes:
    """A signing secret from 64 hex digits, or from a file holding them (``@path``): kept
    out of the command line, where any user of the machine can read it."""
    if text.startswith("@"):
        with open(text[1:]) as f:
            text = f.read()
    key = bytes.fromhex(text.strip())
    if len(key) != 32:
        raise ValueError(f"a MAVLink signing key is 32 bytes (64 hex digits), got {len(key)}")
    return key


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="arcf-mavlink",
        description="Present streams of an arcf-service as MAVLink tracking cameras.")
    ap.add_argument("--mavlink", default="udpout:127.0.0.1:14550",
                    help="pymavlink connection string (default: %(default)s, a local "
                    "QGroundControl or MAVProxy); udpin:HOST:PORT to listen, "
                    "tcp:HOST:PORT, or a serial device,baud")
    ap.add_argument("--camera", action="append", required=True, metavar="STREAM[=COMPID]",
                    help="a stream shown as a camera; component ids default to 100, 101, ...")
    add_service_arguments(ap)
    ap.add_argument("--system-id", type=int, default=1,
                    help="MAVLink system id: the vehicle's (default: %(default)s)")
    add_session_arguments(ap)
    ap.add_argument("--status-hz", type=float, default=10.0,
                    help="CAMERA_TRACKING_IMAGE_STATUS rate until a station sets one")
    ap.add_argument("--link-timeout", type=float, default=5.0,
                    help="seconds without a station heartbeat before the link counts as lost")
    ap.add_argument("--stale-after-s", type=float, default=0.8,
                    help="seconds without a result before a session's status leaves ACTIVE "
                    "(ERROR, no box): the service gone; use the service's stale_after_s "
                    "(default %(default)s; 0: only the service's own stale notices)")
    ap.add_argument("--signing-key", metavar="HEX|@FILE",
                    help="MAVLink 2 signing: the 32-byte secret as 64 hex digits, or @FILE "
                    "holding them; everything sent is signed and only signed messages are "
                    "accepted (a station must hold the same key). Default: no signing")
    ap.add_argument("--max-pixels", type=int, default=4096 * 2160,
                    help="largest frame (from its header or declaration) a track command is "
                    "carried out on (default: %(default)s, DCI 4K)")
    ap.add_argument("--video", action="append", default=[], metavar="STREAM=URI",
                    help="the video a station should show for a camera, advertised in "
                    "VIDEO_STREAM_INFORMATION: rtsp://HOST:PORT/PATH, rtp://:PORT (RTP/UDP, "
                    "the station listens: 5600 for QGroundControl) or udp://:PORT (MPEG-TS)")
    ap.add_argument("--video-key", default=DEFAULT_VIDEO_KEY,
                    help="the service's video_key ('' for none): CompressedVideo streams")
    ap.add_argument("--follow", action="append", default=[], metavar="STREAM",
                    help="keep this camera's target centred: its session's boxes become "
                    "gimbal rate commands (Gimbal Protocol v2), only while tracking")
    ap.add_argument("--gimbal-manager", default="1/1", metavar="SYSID/COMPID",
                    help="the gimbal manager to command (default %(default)s: the autopilot)")
    ap.add_argument("--gimbal-device", type=int, default=0,
                    help="the gimbal device id the manager steers (default 0: all)")
    ap.add_argument("--hfov", type=float, default=60.0,
                    help="the camera's horizontal field of view, degrees (default %(default)s)")
    ap.add_argument("--follow-gain", type=float, default=2.0,
                    help="rate per degree of error, 1/s (default %(default)s)")
    ap.add_argument("--follow-max-rate", type=float, default=60.0,
                    help="fastest rate commanded, deg/s (default %(default)s)")
    ap.add_argument("--follow-hz", type=float, default=30.0,
                    help="most gimbal commands a second (default %(default)s)")
    args = ap.parse_args(argv)
    overrides: dict[str, Any] = dict(args.set)
    try:
        signing_key = _signing_key(args.signing_key) if args.signing_key else None
    except (OSError, ValueError) as exc:
        ap.error(f"--signing-key: {exc}")
    videos: dict[str, VideoStream] = {}
    for item in args.video:
        stream, sep, uri = item.partition("=")
        if not sep:
            ap.error(f"--video needs STREAM=URI, got {item!r}")
        try:
            videos[stream] = VideoStream.parse(uri)
        except ValueError as exc:
            ap.error(f"--video: {exc}")
    cameras = [_camera(c, i) for i, c in enumerate(args.camera)]
    unknown = set(videos) - {c.stream_id for c in cameras}
    if unknown:
        ap.error(f"--video for streams that are no --camera: {sorted(unknown)}")
    follow: GimbalTarget | None = None
    if args.follow:
        system, _, component = args.gimbal_manager.partition("/")
        try:
            follow = GimbalTarget(int(system), int(component), args.gimbal_device,
                                  FollowSettings(hfov_deg=args.hfov, gain=args.follow_gain,
                                                 max_rate_dps=args.follow_max_rate),
                                  args.follow_hz)
        except ValueError as exc:
            ap.error(f"--follow: {exc}")
        unknown = set(args.follow) - {c.stream_id for c in cameras}
        if unknown:
            ap.error(f"--follow for streams that are no --camera: {sorted(unknown)}")
    cameras = [CameraConfig(c.stream_id, c.component_id, videos.get(c.stream_id),
                            follow if c.stream_id in args.follow else None)
               for c in cameras]
    client, stop = connect(args, log)
    if client is None:
        return 2
    with client:
        try:
            check_preset(client, args.preset, overrides)
        except (ValueError, TimeoutError, ServiceError) as exc:
            print(f"arcf-mavlink: {exc}", file=sys.stderr)
            return 2
        endpoint = MavlinkCameras(
            client, args.mavlink, cameras, system_id=args.system_id, preset=args.preset,
            overrides=overrides, status_interval_s=1.0 / args.status_hz if args.status_hz else 0,
            link_timeout_s=args.link_timeout, stale_after_s=args.stale_after_s,
            signing_key=signing_key, max_pixels=args.max_pixels,
            video_key=args.video_key or None).start()
        print(f"arcf-mavlink: {len(cameras)} camera(s) on {args.mavlink}: "
              + ", ".join(f"{c.stream_id} as {args.system_id}/{c.component_id}"
                          for c in cameras), flush=True)
        if args.metrics_port >= 0:
            _, url = serve_counts("mavlink", lambda: endpoint.counts, args.metrics_port)
            print(f"arcf-mavlink: counts on {url}", flush=True)
        while not stop.wait(1.0):
            if not endpoint.alive:  # never a silent zombie: a supervisor restarts us
                print("arcf-mavlink: the MAVLink loop stopped", file=sys.stderr)
                endpoint.close()
                return 1
        endpoint.close()
    return 0


__all__ = [
    "CameraConfig",
    "Denied",
    "MavlinkCameras",
    "VideoStream",
    "check_preset",
    "frame_size",
    "main",
    "point_box",
    "rectangle_box",
    "tracking_status",
    "whole",
]


if __name__ == "__main__":
    raise SystemExit(main())
