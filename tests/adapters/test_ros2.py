"""The ROS 2 adapter against rmw_zenoh's published wire format, with an independent CDR
implementation (pycdr2) playing the ROS 2 nodes: keys, type names and hashes, CDR bytes,
attachments and liveliness tokens, then real frames in as CompressedImage and the service's
results out as Detection2DArray, sessions started and stopped from a topic, a stream that
stops reported as STALE on /diagnostics (and no box to follow) until its images resume."""

import time
from typing import Any

import numpy as np
import pytest
import zenoh
from pycdr2 import make_idl_struct
from pycdr2.types import array, float64, int32, sequence, uint8, uint32
from zenoh.ext import Int64, z_deserialize

from arcf.adapters import ros2_types as rt
from arcf.adapters.ros2 import (
    STALE,
    Ros2Bridge,
    attachment,
    detection_array,
    diagnostics,
    topic_key,
)
from arcf.client import TrackingClient
from arcf.client.transport import open_session
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import wait_until
from arcf.schemas import Result

# --- the published facts (rmw_zenoh docs/design.md and generated type descriptions) ---------
COMPRESSED_IMAGE_HASH = "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"
HEADER_HASH = "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"
DETECTION_2D_ARRAY_HASH = (
    "RIHS01_214274120007f4a683866481336b70310268cfa107aebe9d594a6acf75bda968")
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


# --- the messages, written independently for pycdr2 ------------------------------------------
def struct(typename: str, **fields: Any) -> Any:
    """pycdr2's struct for ROS 2's ``typename`` (``pkg/msg/Name``), its fields in the .msg's
    order: pycdr2's own ``make_idl_struct`` builds the dataclass, so each message is one
    declaration from ROS's definitions (none of it shared with arcf's ros2_types)."""
    return make_idl_struct(typename.rsplit("/", 1)[-1], typename, fields)


Time = struct("builtin_interfaces/msg/Time", sec=int32, nanosec=uint32)
Header = struct("std_msgs/msg/Header", stamp=Time, frame_id=str)
CompressedImage = struct("sensor_msgs/msg/CompressedImage", header=Header, format=str,
                         data=sequence[uint8])
Point = struct("geometry_msgs/msg/Point", x=float64, y=float64, z=float64)
Quaternion = struct("geometry_msgs/msg/Quaternion", x=float64, y=float64, z=float64, w=float64)
Pose = struct("geometry_msgs/msg/Pose", position=Point, orientation=Quaternion)
PoseWithCovariance = struct("geometry_msgs/msg/PoseWithCovariance", pose=Pose,
                            covariance=array[float64, 36])
ObjectHypothesis = struct("vision_msgs/msg/ObjectHypothesis", class_id=str, score=float64)
ObjectHypothesisWithPose = struct("vision_msgs/msg/ObjectHypothesisWithPose",
                                  hypothesis=ObjectHypothesis, pose=PoseWithCovariance)
Point2D = struct("vision_msgs/msg/Point2D", x=float64, y=float64)
Pose2D = struct("vision_msgs/msg/Pose2D", position=Point2D, theta=float64)
BoundingBox2D = struct("vision_msgs/msg/BoundingBox2D", center=Pose2D, size_x=float64,
                       size_y=float64)
Detection2D = struct("vision_msgs/msg/Detection2D", header=Header,
                     results=sequence[ObjectHypothesisWithPose], bbox=BoundingBox2D, id=str)
Detection2DArray = struct("vision_msgs/msg/Detection2DArray", header=Header,
                          detections=sequence[Detection2D])
KeyValue = struct("diagnostic_msgs/msg/KeyValue", key=str, value=str)
DiagnosticStatus = struct("diagnostic_msgs/msg/DiagnosticStatus", level=uint8,  # ROS's "byte"
                          name=str, message=str, hardware_id=str, values=sequence[KeyValue])
DiagnosticArray = struct("diagnostic_msgs/msg/DiagnosticArray", header=Header,
                         status=sequence[DiagnosticStatus])


def test_keys_type_names_and_hashes_are_rmw_zenohs() -> None:
    assert rt.type_hash("sensor_msgs/msg/CompressedImage") == COMPRESSED_IMAGE_HASH
    assert rt.type_hash("std_msgs/msg/Header") == HEADER_HASH
    assert rt.type_hash("vision_msgs/msg/Detection2DArray") == DETECTION_2D_ARRAY_HASH
    assert rt.type_hash("std_msgs/msg/String") == STRING_HASH  # design.md's example
    assert topic_key(0, "/chatter", "std_msgs/msg/String") == \
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert topic_key(3, "/camera/image/compressed/", "sensor_msgs/msg/CompressedImage") == \
        ("3/camera/image/compressed/sensor_msgs::msg::dds_::CompressedImage_/"
         + COMPRESSED_IMAGE_HASH)


def test_attachment_is_two_little_endian_int64_and_a_sized_gid() -> None:
    gid = bytes(range(16))
    raw = attachment(1, 0x18EBBE703EFC03C6, gid)
    assert raw == (bytes.fromhex("0100000000000000") + bytes.fromhex("c603fc3e70beeb18")
                   + b"\x10" + gid)
    with pytest.raises(ValueError):
        attachment(1, 2, b"short")


def test_cdr_bytes_agree_with_an_independent_implementation() -> None:
    image = CompressedImage(Header(Time(1, 2), "cam"), "jpeg", [0xFF, 0xD8, 0xFF, 0xD9])
    ours = rt.deserialize(image.serialize(), rt.COMPRESSED_IMAGE)
    assert (ours.header.frame_id, ours.format, bytes(ours.data)) == ("cam", "jpeg",
                                                                      b"\xff\xd8\xff\xd9")
    assert rt.serialize(ours, rt.COMPRESSED_IMAGE) == image.serialize()
    result = Result(session_id="s1", stream_id="cam1", frame_seq=4, capture_ts_ns=5,
                    box=(11.0, 21.0, 30.0, 40.0), peak=0.5, psr=9.0, aberrance=0.01,
                    aberrance_release=0.02, scale=1.0, confidence=0.875,
                    track_state="coasting", status="tracking", dropped=0, received_ts_ns=6,
                    decode_s=0.001, track_s=0.002, published_ts_ns=7)
    raw = rt.serialize(detection_array(result, (3_000_000_004, "cam_optical")),
                       rt.DETECTION_2D_ARRAY)
    got = Detection2DArray.deserialize(raw)
    assert got.header == Header(Time(3, 4), "cam_optical")
    (d,) = got.detections
    assert (d.id, d.bbox.size_x, d.bbox.size_y) == ("s1", 30.0, 40.0)
    assert (d.bbox.center.position.x, d.bbox.center.position.y) == (25.0, 40.0)  # 0-based
    assert d.results[0].hypothesis == ObjectHypothesis("coasting", 0.875)


def test_a_stale_session_has_no_box_and_reports_stale() -> None:
    nan = float("nan")
    stale = Result(session_id="s1", stream_id="cam1", frame_seq=4, capture_ts_ns=9_000_000_001,
                   box=(nan, nan, nan, nan), peak=nan, psr=nan, aberrance=nan,
                   aberrance_release=nan, scale=nan, status="stale", code="no_frames",
                   message="no frame of stream 'cam1' for 1.0 s", dropped=0, received_ts_ns=6,
                   decode_s=0.0, track_s=0.0, published_ts_ns=7)
    got = Detection2DArray.deserialize(rt.serialize(
        detection_array(stale, (9_000_000_001, "cam_optical")), rt.DETECTION_2D_ARRAY))
    assert got.detections == [] and got.header == Header(Time(9, 1), "cam_optical")
    raw = rt.serialize(diagnostics(stale, "arcf", 3_000_000_004), rt.DIAGNOSTIC_ARRAY)
    (status,) = DiagnosticArray.deserialize(raw).status
    assert (status.level, status.hardware_id, status.name) == (STALE, "cam1", "arcf: cam1 s1")
    assert status.message == "no frame of stream 'cam1' for 1.0 s"
    values = {kv.key: kv.value for kv in status.values}
    assert values["status"] == "stale" and values["code"] == "no_frames"
    assert values["frame_seq"] == "4" and values["track_state"] == ""


needs_data = pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                reason="needs ../shared/data")


@needs_data
@pytest.mark.integration
def test_ros2_nodes_track_through_the_bridge() -> None:
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames[:12]]
    gt = np.asarray(seq.groundtruth)
    service = ServiceProcess(workers=1)
    client = TrackingClient(connect=[service.endpoint])
    # lock-step replay of frames each of which must be answered: the nodes' images and the
    # bridge's frames are put with BLOCK, as every replay here is (a loaded machine's stall
    # would let DROP lose one, and the test would wait for its detections forever)
    bridge = Ros2Bridge(TrackingClient(connect=[service.endpoint], frame_congestion="block"),
                        {"/camera/image/compressed": "cam1"})
    node = open_session("client", connect=[service.endpoint])  # the ROS 2 nodes
    received: list[tuple[bytes, bytes | None]] = []
    health: list[DiagnosticStatus] = []
    replies: list[DiagnosticArray] = []
    results: list[Result] = []
    try:
        out_key = (f"0/arcf/cam1/detections/vision_msgs::msg::dds_::Detection2DArray_/"
                   f"{DETECTION_2D_ARRAY_HASH}")
        sub = node.declare_subscriber(out_key, lambda s: received.append(
            (s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else None)))
        rsub = client.results("cam1", callback=results.append)
        dsub = node.declare_subscriber(
            topic_key(0, "/diagnostics", rt.DIAGNOSTIC_ARRAY),
            lambda s: health.extend(DiagnosticArray.deserialize(s.payload.to_bytes()).status))
        rpsub = node.declare_subscriber(
            topic_key(0, "/arcf/cam1/track_reply", rt.DIAGNOSTIC_ARRAY),
            lambda s: replies.append(DiagnosticArray.deserialize(s.payload.to_bytes())))

        def reply_to(sec: int) -> tuple[DiagnosticStatus, dict[str, str]]:
            """The answer to the request stamped ``sec`` s (its header comes back)."""
            wait_until(lambda: [r for r in list(replies) if r.header.stamp.sec == sec],
                       timeout=30, what=f"the reply to request {sec}")
            ((status,),) = [r.status for r in list(replies) if r.header.stamp.sec == sec]
            return status, {kv.key: kv.value for kv in status.values}

        def about_image(i: int) -> list[tuple[bytes, bytes | None]]:
            """The detections published for image ``i`` (its header): a session's stale
            notices (a pause of this test over a second) carry their own time instead."""
            return [(p, a) for p, a in list(received)
                    if Detection2DArray.deserialize(p).header == Header(Time(1000 + i, 500),
                                                                        "cam_optical")]

        image_key = ("0/camera/image/compressed/sensor_msgs::msg::dds_::CompressedImage_/"
                     + COMPRESSED_IMAGE_HASH)
        track_key = topic_key(0, "/arcf/cam1/track", rt.DETECTION_2D)
        gid = bytes(range(16))

        # the graph sees the node, its publisher and its subscriptions
        tokens = {str(r.ok.key_expr) for r in node.liveliness().get("@ros2_lv/0/**")
                  if r.ok is not None}
        zid = bridge.node.zid
        assert f"@ros2_lv/0/{zid}/0/0/NN/%/%/arcf" in tokens
        assert any(t.startswith(f"@ros2_lv/0/{zid}/0/") and "/MP/%/%/arcf/%arcf%cam1%detections/"
                   "vision_msgs::msg::dds_::Detection2DArray_/" + DETECTION_2D_ARRAY_HASH
                   + "/::,10:,:,:,," in t for t in tokens), tokens
        assert any("/MS/%/%/arcf/%camera%image%compressed/sensor_msgs::msg::dds_::"
                   "CompressedImage_/" + COMPRESSED_IMAGE_HASH in t for t in tokens)

        # a track request from ROS 2: the first frame's ground truth, 0-based centre
        x, y, w, h = gt[0]
        request = Detection2D(Header(Time(1, 0), "req"), [],
                              BoundingBox2D(Pose2D(Point2D(x - 1 + w / 2, y - 1 + h / 2), 0.0),
                                            w, h), "")
        node.put(track_key, request.serialize(), attachment=attachment(1, time.time_ns(), gid))
        started, values = reply_to(1)  # answered: OK, with the session it started
        assert bridge.counts["starts"] == 1 and started.level == 0
        assert values["request"] == "start" and values["code"] == ""
        assert [s.session_id for s in client.status("cam1").sessions] == [values["session_id"]]
        assert started.name == "arcf: cam1 track" and started.hardware_id == "cam1"

        # refused, the session untouched: a session of another stream, a negative size,
        # something that is no Detection2D; each answered ERROR with its reason
        other = client.start("elsewhere", (10.0, 10.0, 40.0, 40.0), preset="bacf")
        for sec, bad in ((2, Detection2D(Header(Time(2, 0), ""), [], request.bbox,
                                         other.session_id)),
                         (3, Detection2D(Header(Time(3, 0), ""), [],
                                         BoundingBox2D(Pose2D(Point2D(50.0, 50.0), 0.0), -4.0,
                                                       10.0), ""))):
            node.put(track_key, bad.serialize(), attachment=attachment(1, time.time_ns(), gid))
            refusal, values = reply_to(sec)
            assert refusal.level == 2 and values["code"] == (
                "no_session" if sec == 2 else "invalid_box"), refusal.message
        node.put(track_key, b"\x00\x01\x00\x00 no detection")
        wait_until(lambda: any(r.status[0].values[2].value == "invalid_request"
                               for r in list(replies)), timeout=30, what="a garbage reply")
        assert bridge.counts["refused"] == 2 and bridge.counts["stops"] == 0
        assert bridge.counts["bad_track"] == 1 and bridge.counts["replies"] == 4
        assert {s.stream_id for s in client.status().sessions} == {"cam1", "elsewhere"}
        client.stop(other.session_id)

        # garbage on the image topic: counted, the bridge goes on
        node.put(image_key, b"\x00\x01\x00\x00not cdr")
        # real frames in, lock-step: each image, then its detection
        def send(i: int) -> None:
            image = CompressedImage(Header(Time(1000 + i, 500), "cam_optical"), "jpeg",
                                    list(data[i % len(data)]))
            node.put(image_key, image.serialize(),
                     attachment=attachment(i + 1, time.time_ns(), gid),
                     congestion_control=zenoh.CongestionControl.BLOCK)
            wait_until(lambda: about_image(i), timeout=30, what=f"image {i}'s detections")

        for i in range(len(data)):
            send(i)
        per_image = [about_image(i) for i in range(len(data))]
        assert [len(d) for d in per_image] == [1] * len(data)
        assert bridge.counts["bad_image"] == 1

        mine = sorted((r for r in results if r.track_state is not None),
                      key=lambda r: r.frame_seq)
        assert [r.frame_seq for r in mine] == list(range(len(data)))
        for i, (((payload, att),), r) in enumerate(zip(per_image, mine, strict=True)):
            msg = Detection2DArray.deserialize(payload)
            assert msg.header == Header(Time(1000 + i, 500), "cam_optical")  # the image's
            (d,) = msg.detections
            bx, by, bw, bh = r.box
            assert (d.bbox.center.position.x, d.bbox.center.position.y) == pytest.approx(
                (bx - 1 + bw / 2, by - 1 + bh / 2), abs=1e-9)
            assert (d.bbox.size_x, d.bbox.size_y) == pytest.approx((bw, bh), abs=1e-9)
            assert d.results[0].hypothesis.class_id == r.track_state.value
            assert d.results[0].hypothesis.score == pytest.approx(r.confidence)
            assert d.id == r.session_id
            assert att is not None and len(att) == 33
            number, _, their_gid = z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(att))
            assert number == i + 1 and len(their_gid) == 16
        session = mine[0].session_id
        assert health and health[-1].name == f"arcf: cam1 {session}"

        # the images stop: the service's stale notice becomes an empty array stamped with
        # its own time (nothing to follow) and a STALE report on /diagnostics
        wait_until(lambda: [r for r in results if r.status == "stale"], timeout=30,
                   what="the service's stale notice")
        (notice, *_) = [r for r in results if r.status == "stale"]
        assert notice.frame_seq == len(data) - 1 and notice.code == "no_frames"
        wait_until(lambda: [h for h in list(health) if h.level == STALE], timeout=10,
                   what="a STALE report")
        (report, *_) = [h for h in list(health) if h.level == STALE]
        assert report.hardware_id == "cam1" and "no frame" in report.message
        assert {kv.key: kv.value for kv in report.values}["status"] == "stale"
        stale_arrays = [Detection2DArray.deserialize(p) for p, _ in list(received)]
        stale_arrays = [m for m in stale_arrays if m.header.stamp.sec > 2000]
        assert stale_arrays and all(m.detections == [] for m in stale_arrays)
        assert stale_arrays[0].header.frame_id == "cam_optical"
        # an image again: its detection, and the report leaves STALE
        after = len(health)
        send(len(data))
        ((payload, _),) = about_image(len(data))
        (d,) = Detection2DArray.deserialize(payload).detections
        assert d.id == session
        wait_until(lambda: [h for h in health[after:] if h.level != STALE], timeout=10,
                   what="a report that leaves STALE")

        # stop from ROS 2 (a box of size 0): the session ends, an empty array says so
        stop = Detection2D(Header(Time(4, 0), ""), [],
                           BoundingBox2D(Pose2D(Point2D(0.0, 0.0), 0.0), 0.0, 0.0), "")
        node.put(track_key, stop.serialize(), attachment=attachment(2, time.time_ns(), gid))
        stopped, values = reply_to(4)
        assert stopped.level == 0 and values == {"request": "stop", "session_id": session,
                                                 "code": "", "stream_id": "cam1"}
        # the stop's array: about the session's last image
        wait_until(lambda: len(about_image(len(data))) >= 2, timeout=10,
                   what="the stop's empty array")
        assert Detection2DArray.deserialize(about_image(len(data))[-1][0]).detections == []
        assert client.status("cam1").sessions == []

        # a session of the stream that another station started: the bridge holds no control
        # token for it, so the service refuses to let it re-draw it (answered ERROR,
        # forbidden), and the session goes on
        theirs = client.start("cam1", (10.0, 10.0, 40.0, 40.0), preset="bacf")
        send(len(data) + 1)
        seen = Detection2DArray.deserialize(about_image(len(data) + 1)[0][0]).detections
        assert [d.id for d in seen] == [theirs.session_id]
        redraw = Detection2D(Header(Time(5, 0), ""), [], request.bbox, theirs.session_id)
        node.put(track_key, redraw.serialize(), attachment=attachment(3, time.time_ns(), gid))
        refusal, values = reply_to(5)
        assert refusal.level == 2 and values["code"] == "forbidden", refusal.message
        assert [s.session_id for s in client.status("cam1").sessions] == [theirs.session_id]
        client.stop(theirs.session_id)
        sub.undeclare()
        dsub.undeclare()
        rpsub.undeclare()
        rsub.close()
    finally:
        bridge.close()
        bridge.client.close()
        node.close()
        client.close()
        assert service.stop() == 0




def test_an_interrupted_session_is_kept_an_ended_one_is_not(offline_client: Any) -> None:
    """The ``stopped`` result of an instance that stops (code ``interrupted``) leaves the
    stream's session in place, to resume under its id; one the service ended clears it."""
    from arcf.schemas import Result

    ros = open_session("peer", listen=[])  # the ROS 2 side, on no network
    bridge = Ros2Bridge(offline_client, {"/camera/image/compressed": "cam1"}, ros_session=ros)
    try:
        s = bridge.streams["cam1"]
        s.session_id = "s1"
        nan = float("nan")

        def stopped(code: str) -> Result:
            return Result(session_id="s1", stream_id="cam1", frame_seq=3, capture_ts_ns=1,
                          box=[nan] * 4, peak=nan, psr=nan, aberrance=nan,
                          aberrance_release=nan, scale=nan, status="stopped", dropped=0,
                          code=code, message="why", received_ts_ns=1, decode_s=0.0,
                          track_s=0.0, published_ts_ns=1)

        seen = offline_client.callbacks["results"]
        seen(stopped("interrupted"))
        assert s.session_id == "s1"
        seen(stopped("session_expired"))
        assert s.session_id is None
    finally:
        bridge.close()
        ros.close()
