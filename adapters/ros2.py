"""ROS 2 over Zenoh: images in from ROS 2 nodes, detections out to them, sessions from a topic.

ROS 2 nodes running ``rmw_zenoh`` publish a topic on the Zenoh key
``<domain>/<topic without its leading and trailing '/'>/<DDS type name>/<RIHS01 type hash>``,
the payload CDR-encoded, each sample with an attachment (sequence number, source timestamp,
publisher gid), and announce nodes, publishers and subscriptions with liveliness tokens under
``@ros2_lv/…``, which is how ``ros2 topic list`` sees them. :class:`Ros2Bridge` is such a node
(``/arcf`` by default), on the same Zenoh network as the service:

* it subscribes to ``sensor_msgs/msg/CompressedImage`` topics (jpeg or png) and publishes each
  image as a frame of a stream of the service; with ``bridge_keys`` also on the keys of
  ``zenoh-bridge-ros2dds`` (the topic name as key, raw CDR, no attachment);
* it publishes every result of the stream's sessions on ``/arcf/<stream>/detections`` as a
  ``vision_msgs/msg/Detection2DArray`` with the source image's header (stamp and frame id):
  one detection, its box in pixels (centre and size, 0-based as ROS images are), its ``id``
  the session, its hypothesis ``class_id`` the track state and ``score`` the confidence;
  results without a box (error, stopped) give an empty array, and so does a session gone
  stale (its stream's frames stopped), stamped with the notice's time: nothing to follow;
* it reports each session's health on ``/diagnostics`` (``diagnostic_msgs/msg/
  DiagnosticArray``, what ``rqt_robot_monitor`` and ``diagnostic_aggregator`` read): level
  STALE while its stream sends no frames, ERROR on an error result, WARN while the target
  is coasting or lost, OK otherwise; at once when the level changes, else at most once a
  second (a stale session's notices repeat, so a stale report does too);
* a ``vision_msgs/msg/Detection2D`` on ``/arcf/<stream>/track`` starts a session on the stream
  from its ``bbox`` (pixels), or re-initialises the session named by its ``id`` (empty: the
  bridge's own session of that stream; only sessions of that stream); a 0 x 0 box stops it,
  and a box with a negative, NaN or half-zero size is refused. Every request is answered on
  ``/arcf/<stream>/track_reply`` (``diagnostic_msgs/msg/DiagnosticArray``, the request's
  header for the requester to match, one status: OK with the session, or ERROR with the
  reason and its code).

Wire facts from rmw_zenoh (``docs/design.md``, ``liveliness_utils.cpp``,
``attachment_helpers.cpp``): the attachment is the sequence number and the source timestamp as
little-endian int64 and the 16-byte gid with its length (zenoh's serialisation, 33 bytes), as
rmw_zenoh writes it since Jazzy 0.2.4 / Rolling 0.6.0; tokens are
``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP|MS>/<enclave>/<namespace>/<node>``
followed, for topics, by ``/<topic>/<type>/<hash>/<qos>``, with every ``/`` inside a name
written ``%``. CDR and type hashes come from ``rosbags`` (:mod:`arcf.adapters.ros2_types`).
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import queue
import sys
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh
from zenoh.ext import Int64, z_serialize

from arcf.client import ServiceError, TrackingClient
from arcf.schemas import ErrorCode, Result, ResultStatus, TrackState

from . import ros2_types as rt
from ._command import (
    add_service_arguments,
    add_session_arguments,
    check_preset,
    connect,
    serve_counts,
)

log = logging.getLogger(__name__)

#: rmw_zenoh's QoS string for RELIABLE, VOLATILE, KEEP_LAST 10 (rclcpp/rclpy's default):
#: only the values differing from rmw_zenoh's own defaults are written
DEFAULT_QOS = "::,10:,:,:,,"
#: source frames remembered for the results' headers, per stream
HEADERS_KEPT = 512
#: a session's health is reported at least this often while its results come (and at once
#: when its level changes)
DIAGNOSTICS_PERIOD_S = 1.0
#: ``diagnostic_msgs/msg/DiagnosticStatus`` levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3


def mangle(name: str) -> str:
    """A name inside a liveliness token: every ``/`` becomes ``%`` (``/`` alone: ``%``)."""
    return name.replace("/", "%")


def topic_key(domain_id: int, topic: str, ros_type: str) -> str:
    """The Zenoh key rmw_zenoh publishes ``topic`` of type ``ros_type`` on."""
    return f"{domain_id}/{topic.strip('/')}/{rt.dds_type_name(ros_type)}/{rt.type_hash(ros_type)}"


def attachment(sequence_number: int, timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's per-sample attachment (33 bytes)."""
    if len(gid) != 16:
        raise ValueError("a gid is 16 bytes")
    return z_serialize((Int64(sequence_number), Int64(timestamp_ns), gid)).to_bytes()


@dataclass(frozen=True)
class Entity:
    """A node's publisher (``MP``) or subscription (``MS``) as the ROS 2 graph sees it."""

    kind: str
    topic: str
    ros_type: str
    entity_id: int


class Ros2Node:
    """The liveliness side of a ROS 2 node on Zenoh: its token and its entities' tokens."""

    def __init__(self, session: zenoh.Session, domain_id: int, name: str,
                 namespace: str = "/", enclave: str = "/") -> None:
        self.session, self.domain_id = session, domain_id
        self.name, self.namespace, self.enclave = name, namespace, enclave
        self.zid = str(session.info.zid())
        self._next_id = 1
        self._tokens = [session.liveliness().declare_token(self.token_key())]

    def _prefix(self, entity_id: int, kind: str) -> str:
        return (f"@ros2_lv/{self.domain_id}/{self.zid}/0/{entity_id}/{kind}/"
                f"{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}")

    def token_key(self, entity: Entity | None = None) -> str:
        if entity is None:
            return self._prefix(0, "NN")
        return (f"{self._prefix(entity.entity_id, entity.kind)}/{mangle(entity.topic)}/"
                f"{rt.dds_type_name(entity.ros_type)}/{rt.type_hash(entity.ros_type)}/"
                f"{DEFAULT_QOS}")

    def entity(self, kind: str, topic: str, ros_type: str) -> Entity:
        """Announce a publisher or a subscription (its token lives as long as the node)."""
        e = Entity(kind, topic, ros_type, self._next_id)
        self._next_id += 1
        self._tokens.append(self.session.liveliness().declare_token(self.token_key(e)))
        return e

    def gid(self, entity: Entity) -> bytes:
        """A 16-byte id unique to the entity (rmw_zenoh hashes the token key; receivers only
        pass it on)."""
        return hashlib.blake2b(self.token_key(entity).encode(), digest_size=16).digest()

    def close(self) -> None:
        for token in self._tokens:
            token.undeclare()
        self._tokens = []


class Ros2Publisher:
    """A ROS 2 publisher on rmw_zenoh's key, with its attachment per sample."""

    def __init__(self, node: Ros2Node, topic: str, ros_type: str) -> None:
        self.ros_type = ros_type
        self.key = topic_key(node.domain_id, topic, ros_type)
        self.entity = node.entity("MP", topic, ros_type)
        self._gid = node.gid(self.entity)
        self._pub = node.session.declare_publisher(self.key)
        self._seq = 0
        self._lock = threading.Lock()

    def publish(self, message: Any) -> None:
        payload = rt.serialize(message, self.ros_type)
        with self._lock:
            self._seq += 1
            self._pub.put(payload, attachment=attachment(self._seq, time.time_ns(), self._gid))

    def close(self) -> None:
        self._pub.undeclare()


def _stamp(ns: int) -> Any:
    return rt.message("builtin_interfaces/msg/Time", sec=ns // 1_000_000_000,
                      nanosec=ns % 1_000_000_000)


def _header(stamp_ns: int, frame_id: str) -> Any:
    return rt.message("std_msgs/msg/Header", stamp=_stamp(stamp_ns), frame_id=frame_id)


def detection_array(result: Result, header: tuple[int, str]) -> Any:
    """A result as ``vision_msgs/msg/Detection2DArray`` (see the module docstring)."""
    h = _header(*header)
    detections = []
    if result.track_state is not None and all(np.isfinite(result.box)):
        x, y, w, h_ = result.box
        zero_pose = rt.message(
            "geometry_msgs/msg/PoseWithCovariance",
            pose=rt.message("geometry_msgs/msg/Pose",
                            position=rt.message("geometry_msgs/msg/Point", x=0.0, y=0.0, z=0.0),
                            orientation=rt.message("geometry_msgs/msg/Quaternion", x=0.0,
                                                   y=0.0, z=0.0, w=1.0)),
            covariance=np.zeros(36))
        hypothesis = rt.message(
            "vision_msgs/msg/ObjectHypothesisWithPose",
            hypothesis=rt.message("vision_msgs/msg/ObjectHypothesis",
                                  class_id=result.track_state.value,
                                  score=float(result.confidence or 0.0)),
            pose=zero_pose)
        bbox = rt.message(
            "vision_msgs/msg/BoundingBox2D",
            center=rt.message("vision_msgs/msg/Pose2D",
                              position=rt.message("vision_msgs/msg/Point2D",
                                                  x=x - 1.0 + w / 2, y=y - 1.0 + h_ / 2),
                              theta=0.0),
            size_x=float(w), size_y=float(h_))
        detections.append(rt.message(rt.DETECTION_2D, header=h, results=[hypothesis],
                                     bbox=bbox, id=result.session_id))
    return rt.message(rt.DETECTION_2D_ARRAY, header=h, detections=detections)


def diagnostic_level(result: Result) -> int:
    """A result's ``DiagnosticStatus`` level: STALE for a stream without frames (ROS's own
    word for a sensor that stopped reporting), ERROR for an error, WARN while the target is
    probably hidden or gone (the box is a guess), OK otherwise."""
    if result.status == ResultStatus.STALE:
        return STALE
    if result.status == ResultStatus.ERROR:
        return ERROR
    if result.track_state in (TrackState.COASTING, TrackState.LOST):
        return WARN
    return OK


def diagnostics(result: Result, node_name: str, stamp_ns: int) -> Any:
    """A session's health as a ``diagnostic_msgs/msg/DiagnosticArray`` of one status: named
    ``<node>: <stream> <session>``, the stream as ``hardware_id``, the result's status, track
    state, confidence and frame as values."""
    if result.message:
        text = result.message
    elif result.track_state is not None:
        text = f"{result.track_state.value}, confidence {result.confidence or 0.0:.2f}"
    else:
        text = result.status.value
    values = {"session_id": result.session_id, "status": result.status.value,
              "track_state": result.track_state.value if result.track_state else "",
              "confidence": "" if result.confidence is None else f"{result.confidence:.3f}",
              "frame_seq": str(result.frame_seq),
              "code": result.code.value if result.code is not None else ""}
    status = rt.message(
        "diagnostic_msgs/msg/DiagnosticStatus", level=diagnostic_level(result),
        name=f"{node_name}: {result.stream_id} {result.session_id}", message=text,
        hardware_id=result.stream_id,
        values=[rt.message("diagnostic_msgs/msg/KeyValue", key=k, value=v)
                for k, v in values.items()])
    return rt.message(rt.DIAGNOSTIC_ARRAY, header=_header(stamp_ns, ""), status=[status])


@dataclass(frozen=True)
class TrackReply:
    """What a track request got: carried out (``ok``) or not, which request it was
    (``start``, ``reinit``, ``stop``), the session, and why not (a code and a text)."""

    ok: bool
    request: str
    session_id: str | None
    code: str | None
    text: str


def track_reply(reply: TrackReply, stream_id: str, node_name: str, header: Any) -> Any:
    """A track request's answer as a ``diagnostic_msgs/msg/DiagnosticArray``: the request's
    own header (its stamp and frame id: how the requester matches them), one status named
    ``<node>: <stream> track``, OK or ERROR, the text, and as values the request, the
    session and the code."""
    values = {"request": reply.request, "session_id": reply.session_id or "",
              "code": reply.code or "", "stream_id": stream_id}
    status = rt.message(
        "diagnostic_msgs/msg/DiagnosticStatus", level=OK if reply.ok else ERROR,
        name=f"{node_name}: {stream_id} track", message=reply.text, hardware_id=stream_id,
        values=[rt.message("diagnostic_msgs/msg/KeyValue", key=k, value=v)
                for k, v in values.items()])
    return rt.message(rt.DIAGNOSTIC_ARRAY,
                      header=header if header is not None else _header(time.time_ns(), ""),
                      status=[status])


def _encoding(fmt: str) -> str | None:
    """``CompressedImage.format`` ("jpeg", "png", "bgr8; jpeg compressed bgr8", ...) as a
    frame encoding of the service."""
    low = fmt.lower()
    if "jpeg" in low or "jpg" in low:
        return "jpeg"
    if "png" in low:
        return "png"
    return None


@dataclass
class _Stream:
    stream_id: str
    topic: str
    track_topic: str
    publisher: Ros2Publisher
    replies: Ros2Publisher
    seq: int = 0
    headers: OrderedDict[int, tuple[int, str]] | None = None
    session_id: str | None = None
    #: the live sessions of this stream (seen in its results): the only ones its track topic
    #: may re-initialise or stop
    sessions: set[str] | None = None


class _Warnings:
    """At most one log line per kind every ``every_s`` seconds, with the count it stands
    for: a hostile peer cannot fill the log."""

    def __init__(self, every_s: float = 10.0) -> None:
        self.every_s = every_s
        self._last: dict[str, float] = {}
        self._held: Counter[str] = Counter()

    def __call__(self, kind: str, text: str, *args: Any) -> None:
        now = time.monotonic()
        if now - self._last.get(kind, -1e9) < self.every_s:
            self._held[kind] += 1
            return
        held, self._held[kind] = self._held[kind], 0
        self._last[kind] = now
        log.warning(text + (f" (and {held} more like it)" if held else ""), *args)


class Ros2Bridge:
    """A ROS 2 node (``/<name>``) between ROS 2 image topics and the service's streams.

    ``images`` maps image topics to stream ids. ``ros_session`` is the Zenoh session of the
    ROS 2 side (default: the client's own, when the service and the ROS 2 nodes share a Zenoh
    network, e.g. rmw_zenoh's router on 7447). ``counts`` tallies images, frames, results and
    refusals (unsupported formats, undecodable CDR).
    """

    def __init__(self, client: TrackingClient, images: Mapping[str, str], *,
                 domain_id: int = 0, node_name: str = "arcf", namespace: str = "/",
                 ros_session: zenoh.Session | None = None, preset: str = "arcf-hc",
                 overrides: Mapping[str, Any] | None = None, bridge_keys: bool = False) -> None:
        if not images:
            raise ValueError("at least one image topic is needed")
        self.client = client
        self.session = ros_session or client.session
        self.preset, self.overrides = preset, dict(overrides or {})
        self.node = Ros2Node(self.session, domain_id, node_name, namespace)
        self.node_name = node_name
        self.diagnostics = Ros2Publisher(self.node, "/diagnostics", rt.DIAGNOSTIC_ARRAY)
        #: session -> (level, monotonic time) of its last health report
        self._reported: dict[str, tuple[int, float]] = {}
        self.counts: Counter[str] = Counter()
        self._warn = _Warnings()
        self._lock = threading.Lock()
        self._work: queue.Queue[tuple[str, _Stream, bytes] | None] = queue.Queue(maxsize=64)
        self._subs: list[Any] = []
        self.streams: dict[str, _Stream] = {}
        base = namespace.rstrip("/")
        for topic, stream_id in images.items():
            out = f"{base}/{node_name}/{stream_id}/detections"
            track = f"{base}/{node_name}/{stream_id}/track"
            s = _Stream(stream_id, topic, track,
                        Ros2Publisher(self.node, out, rt.DETECTION_2D_ARRAY),
                        Ros2Publisher(self.node, f"{track}_reply", rt.DIAGNOSTIC_ARRAY),
                        headers=OrderedDict(), sessions=set())
            self.streams[stream_id] = s
            self.node.entity("MS", topic, rt.COMPRESSED_IMAGE)
            self.node.entity("MS", track, rt.DETECTION_2D)
            keys = [("image", topic_key(domain_id, topic, rt.COMPRESSED_IMAGE)),
                    ("track", topic_key(domain_id, track, rt.DETECTION_2D))]
            if bridge_keys:  # zenoh-bridge-ros2dds: the topic name is the key
                keys += [("image", topic.strip("/")), ("track", track.strip("/"))]
            for kind, key in keys:
                self._subs.append(self.session.declare_subscriber(
                    key, self._on_sample(kind, s)))
            self._subs.append(client.results(stream_id, callback=self._on_result(s)))
        self._stop = False
        self._thread = threading.Thread(target=self._loop, name="ros2-bridge", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ ROS 2 -> service
    def _on_sample(self, kind: str, s: _Stream) -> Any:
        def on_sample(sample: Any) -> None:
            try:  # decoded and forwarded on the bridge's thread, never in Zenoh's callback
                self._work.put_nowait((kind, s, sample.payload.to_bytes()))
            except queue.Full:
                self.counts["dropped"] += 1
        return on_sample

    def _loop(self) -> None:
        while True:
            item = self._work.get()
            if item is None:
                return
            kind, s, payload = item
            try:
                if kind == "image":
                    self._image(s, payload)
                else:
                    self._track(s, payload)
            except Exception as exc:  # one bad sample never stops the bridge
                self.counts[f"bad_{kind}"] += 1
                self._warn(f"bad_{kind}", "ros2: %s refused: %s",
                           s.topic if kind == "image" else s.track_topic, exc)
                if kind == "track":  # not even a Detection2D: answered all the same
                    self._reply(s, None, TrackReply(False, "", None, "invalid_request",
                                                    f"not a vision_msgs/Detection2D: {exc}"))

    def _image(self, s: _Stream, payload: bytes) -> None:
        msg = rt.deserialize(payload, rt.COMPRESSED_IMAGE)
        encoding = _encoding(msg.format)
        if encoding is None:
            self.counts["unsupported_format"] += 1
            self._warn("format", "ros2: %s: format %r is neither jpeg nor png", s.topic,
                       msg.format)
            return
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self._lock:
            seq = s.seq
            s.seq += 1
            assert s.headers is not None
            s.headers[seq] = (stamp, msg.header.frame_id)
            while len(s.headers) > HEADERS_KEPT:
                s.headers.popitem(last=False)
        self.client.publish_frame(s.stream_id, data=bytes(msg.data), encoding=encoding,
                                  seq=seq, capture_ts_ns=stamp or time.time_ns())
        self.counts["images"] += 1

    def _track(self, s: _Stream, payload: bytes) -> None:
        det = rt.deserialize(payload, rt.DETECTION_2D)
        self._reply(s, det.header, self._carry_out(s, det))

    def _carry_out(self, s: _Stream, det: Any) -> TrackReply:
        """A track request carried out, or refused, and what to answer."""
        cx, cy = det.bbox.center.position.x, det.bbox.center.position.y
        w, h = det.bbox.size_x, det.bbox.size_y
        session = det.id or s.session_id
        request = "stop" if w == 0 and h == 0 else "reinit" if session else "start"
        if not all(np.isfinite((cx, cy, w, h))) or w < 0 or h < 0 or (w == 0) != (h == 0):
            self.counts["refused"] += 1
            self._warn("track", "ros2: %s: box %s refused (a stop is a 0 x 0 box)",
                       s.track_topic, (cx, cy, w, h))
            return TrackReply(False, request, session, "invalid_box",
                              f"box {(cx, cy, w, h)} refused: sizes must be finite and "
                              "positive (a stop is a 0 x 0 box)")
        assert s.sessions is not None
        if det.id and det.id not in s.sessions and det.id != s.session_id:
            self.counts["refused"] += 1
            self._warn("track", "ros2: %s: session %r is not a session of stream %r",
                       s.track_topic, det.id, s.stream_id)
            return TrackReply(False, request, det.id, "no_session",
                              f"session {det.id!r} is not a session of stream "
                              f"{s.stream_id!r}")
        try:
            if request == "stop":
                if session:
                    self.client.stop(session)
                    if session == s.session_id:
                        s.session_id = None
                self.counts["stops"] += 1
                return TrackReply(True, request, session, None,
                                  f"stopped session {session}" if session
                                  else "no session to stop")
            box = (cx - w / 2 + 1.0, cy - h / 2 + 1.0, w, h)  # 0-based centre -> 1-based box
            if session:
                self.client.reinit(session, box)
                self.counts["reinits"] += 1
                return TrackReply(True, request, session, None,
                                  f"session {session} re-initialised")
            ack = self.client.start(s.stream_id, box, preset=self.preset,
                                    overrides=self.overrides)
            s.session_id = ack.session_id
            self.counts["starts"] += 1
            return TrackReply(True, request, ack.session_id, None,
                              f"session {ack.session_id} started ({self.preset})")
        except (ServiceError, TimeoutError) as exc:
            self.counts["refused"] += 1
            self._warn("track", "ros2: %s: refused by the service: %s", s.track_topic, exc)
            code = exc.code if isinstance(exc, ServiceError) else "timeout"
            return TrackReply(False, request, session, code, str(exc))

    def _reply(self, s: _Stream, header: Any, reply: TrackReply) -> None:
        s.replies.publish(track_reply(reply, s.stream_id, self.node_name, header))
        self.counts["replies"] += 1

    # ------------------------------------------------------------------ service -> ROS 2
    def _on_result(self, s: _Stream) -> Any:
        def on_result(result: Result) -> None:
            with self._lock:
                assert s.headers is not None
                header = s.headers.get(result.frame_seq, (result.capture_ts_ns, ""))
                if result.status == ResultStatus.STALE:  # about no image: the notice's time
                    last = next(reversed(s.headers.values()), (0, ""))
                    header = (result.capture_ts_ns, last[1])
            assert s.sessions is not None
            # interrupted (its instance stopped): not over, it resumes under its id
            if result.status == ResultStatus.STOPPED and result.code != ErrorCode.INTERRUPTED:
                s.sessions.discard(result.session_id)
                if result.session_id == s.session_id:
                    s.session_id = None
                if result.code is not None:  # ended by the service, not by a request
                    log.info("ros2: session %s of %s ended: %s", result.session_id,
                             s.stream_id, result.message)
            else:
                s.sessions.add(result.session_id)
            s.publisher.publish(detection_array(result, header))
            self.counts["detections"] += 1
            self._report(result)
        return on_result

    def _report(self, result: Result) -> None:
        """The session's health on ``/diagnostics``: when its level changes, else at most
        every ``DIAGNOSTICS_PERIOD_S`` (results come at the frame rate; diagnostics are read
        at about 1 Hz), and once more when it ends."""
        level, now = diagnostic_level(result), time.monotonic()
        with self._lock:
            last = self._reported.get(result.session_id)
            ended = result.status == ResultStatus.STOPPED
            if ended:
                self._reported.pop(result.session_id, None)
            elif last is not None and last[0] == level and now - last[1] < DIAGNOSTICS_PERIOD_S:
                return
            else:
                self._reported[result.session_id] = (level, now)
        self.diagnostics.publish(diagnostics(result, self.node_name, time.time_ns()))
        self.counts["diagnostics"] += 1

    def close(self) -> None:
        self._work.put(None)
        self._thread.join(timeout=5)
        for sub in self._subs:
            if hasattr(sub, "close"):  # the SDK's result streams
                sub.close()
            else:  # Zenoh subscribers
                sub.undeclare()
        for s in self.streams.values():
            s.publisher.close()
            s.replies.close()
        self.diagnostics.close()
        self.node.close()


# ---------------------------------------------------------------------------------- command
def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="arcf-ros2",
        description="A ROS 2 node (rmw_zenoh) between ROS 2 image topics and arcf-service.")
    ap.add_argument("--image", action="append", required=True, metavar="TOPIC=STREAM",
                    help="a sensor_msgs/msg/CompressedImage topic and the stream it feeds")
    add_service_arguments(ap)
    ap.add_argument("--ros-connect", default=None,
                    help="rmw_zenoh's router, when not the same Zenoh network (e.g. "
                    "tcp/127.0.0.1:7448)")
    ap.add_argument("--domain-id", type=int, default=0)
    ap.add_argument("--node-name", default="arcf")
    add_session_arguments(ap)
    ap.add_argument("--bridge-keys", action="store_true",
                    help="also the keys of zenoh-bridge-ros2dds (topic name, raw CDR)")
    args = ap.parse_args(argv)
    overrides: dict[str, Any] = dict(args.set)
    images = {}
    for item in args.image:
        topic, sep, stream = item.partition("=")
        if not sep or not topic.startswith("/"):
            ap.error(f"--image needs /TOPIC=STREAM, got {item!r}")
        images[topic] = stream
    from arcf.client.transport import open_session

    client, stop = connect(args, log)
    if client is None:
        return 2
    with client:
        try:  # refused now rather than at the first track request
            check_preset(client, args.preset, overrides)
        except (ValueError, TimeoutError, ServiceError) as exc:
            print(f"arcf-ros2: {exc}", file=sys.stderr)
            return 2
        ros = open_session("client", connect=[args.ros_connect]) if args.ros_connect else None
        bridge = Ros2Bridge(client, images, domain_id=args.domain_id, node_name=args.node_name,
                            ros_session=ros, preset=args.preset, overrides=overrides,
                            bridge_keys=args.bridge_keys)
        print(f"arcf-ros2: node /{args.node_name} in domain {args.domain_id}: "
              + ", ".join(f"{t} -> {s} -> /{args.node_name}/{s}/detections"
                          for t, s in images.items()), flush=True)
        if args.metrics_port >= 0:
            _, url = serve_counts("ros2", lambda: bridge.counts, args.metrics_port)
            print(f"arcf-ros2: counts on {url}", flush=True)
        stop.wait()
        bridge.close()
        if ros is not None:
            ros.close()
    return 0


__all__ = [
    "Entity",
    "Ros2Bridge",
    "Ros2Node",
    "Ros2Publisher",
    "TrackReply",
    "attachment",
    "detection_array",
    "diagnostic_level",
    "diagnostics",
    "main",
    "mangle",
    "topic_key",
    "track_reply",
]


if __name__ == "__main__":
    raise SystemExit(main())
