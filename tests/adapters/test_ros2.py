"""The ROS 2 adapter against rmw_zenoh's published wire format, with an independent CDR
implementation (pycdr2) playing the ROS 2 nodes: keys, type names and hashes, CDR bytes,
attachments and liveliness tokens, then real frames in as CompressedImage and the service's
results out as Detection2DArray, sessions started and stopped from a topic.

(No ``from __future__ import annotations``: pycdr2 reads the dataclasses' real types.)"""


import time
from dataclasses import dataclass

import numpy as np
import pytest
import zenoh
from pycdr2 import IdlStruct
from pycdr2.types import array, float64, int32, sequence, uint8, uint32
from zenoh.ext import Int64, z_deserialize

from adapters import ros2_types as rt
from adapters.ros2 import Ros2Bridge, attachment, detection_array, topic_key
from arcf.data import data_root
from arcf.eval import load_dataset
from loadtools.procs import ServiceProcess
from schemas import Result
from service.client import TrackingClient
from service.transport import open_session

# --- the published facts (rmw_zenoh docs/design.md and generated type descriptions) ---------
COMPRESSED_IMAGE_HASH = "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"
HEADER_HASH = "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"
DETECTION_2D_ARRAY_HASH = (
    "RIHS01_214274120007f4a683866481336b70310268cfa107aebe9d594a6acf75bda968")
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


# --- the messages, written independently for pycdr2 ------------------------------------------
@dataclass
class Time(IdlStruct, typename="builtin_interfaces/msg/Time"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs/msg/Header"):
    stamp: Time
    frame_id: str


@dataclass
class CompressedImage(IdlStruct, typename="sensor_msgs/msg/CompressedImage"):
    header: Header
    format: str
    data: sequence[uint8]


@dataclass
class Point(IdlStruct, typename="geometry_msgs/msg/Point"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs/msg/Quaternion"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs/msg/Pose"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs/msg/PoseWithCovariance"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class ObjectHypothesis(IdlStruct, typename="vision_msgs/msg/ObjectHypothesis"):
    class_id: str
    score: float64


@dataclass
class ObjectHypothesisWithPose(IdlStruct, typename="vision_msgs/msg/ObjectHypothesisWithPose"):
    hypothesis: ObjectHypothesis
    pose: PoseWithCovariance


@dataclass
class Point2D(IdlStruct, typename="vision_msgs/msg/Point2D"):
    x: float64
    y: float64


@dataclass
class Pose2D(IdlStruct, typename="vision_msgs/msg/Pose2D"):
    position: Point2D
    theta: float64


@dataclass
class BoundingBox2D(IdlStruct, typename="vision_msgs/msg/BoundingBox2D"):
    center: Pose2D
    size_x: float64
    size_y: float64


@dataclass
class Detection2D(IdlStruct, typename="vision_msgs/msg/Detection2D"):
    header: Header
    results: sequence[ObjectHypothesisWithPose]
    bbox: BoundingBox2D
    id: str


@dataclass
class Detection2DArray(IdlStruct, typename="vision_msgs/msg/Detection2DArray"):
    header: Header
    detections: sequence[Detection2D]


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
    bridge = Ros2Bridge(TrackingClient(connect=[service.endpoint]),
                        {"/camera/image/compressed": "cam1"})
    node = open_session("client", connect=[service.endpoint])  # the ROS 2 nodes
    received: list[tuple[bytes, bytes | None]] = []
    results: list[Result] = []
    try:
        out_key = (f"0/arcf/cam1/detections/vision_msgs::msg::dds_::Detection2DArray_/"
                   f"{DETECTION_2D_ARRAY_HASH}")
        sub = node.declare_subscriber(out_key, lambda s: received.append(
            (s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else None)))
        rsub = client.results("cam1", callback=results.append)
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
        request = Detection2D(Header(Time(0, 0), ""), [],
                              BoundingBox2D(Pose2D(Point2D(x - 1 + w / 2, y - 1 + h / 2), 0.0),
                                            w, h), "")
        node.put(track_key, request.serialize(), attachment=attachment(1, time.time_ns(), gid))
        deadline = time.monotonic() + 10
        while bridge.counts["starts"] < 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert bridge.counts["starts"] == 1

        # refused, the session untouched: a session of another stream, a negative size
        other = client.start("elsewhere", (10.0, 10.0, 40.0, 40.0), preset="bacf")
        for bad in (Detection2D(Header(Time(0, 0), ""), [], request.bbox, other.session_id),
                    Detection2D(Header(Time(0, 0), ""), [],
                                BoundingBox2D(Pose2D(Point2D(50.0, 50.0), 0.0), -4.0, 10.0),
                                "")):
            node.put(track_key, bad.serialize(), attachment=attachment(1, time.time_ns(), gid))
        deadline = time.monotonic() + 10
        while bridge.counts["refused"] < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert bridge.counts["refused"] == 2 and bridge.counts["stops"] == 0
        assert {s.stream_id for s in client.status().sessions} == {"cam1", "elsewhere"}
        client.stop(other.session_id)

        # garbage on the image topic: counted, the bridge goes on
        node.put(image_key, b"\x00\x01\x00\x00not cdr")
        # real frames in, lock-step: each image, then its detection
        for i, jpeg in enumerate(data):
            image = CompressedImage(Header(Time(1000 + i, 500), "cam_optical"), "jpeg",
                                    list(jpeg))
            node.put(image_key, image.serialize(),
                     attachment=attachment(i + 1, time.time_ns(), gid))
            deadline = time.monotonic() + 15
            while len(received) <= i and time.monotonic() < deadline:
                time.sleep(0.01)
        assert len(received) == len(data)
        assert bridge.counts["bad_image"] == 1

        mine = sorted((r for r in results if r.track_state is not None),
                      key=lambda r: r.frame_seq)
        assert [r.frame_seq for r in mine] == list(range(len(data)))
        for i, ((payload, att), r) in enumerate(zip(received, mine, strict=True)):
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

        # stop from ROS 2 (a box of size 0): the session ends, an empty array says so
        stop = Detection2D(Header(Time(0, 0), ""), [],
                           BoundingBox2D(Pose2D(Point2D(0.0, 0.0), 0.0), 0.0, 0.0), "")
        node.put(track_key, stop.serialize(), attachment=attachment(2, time.time_ns(), gid))
        deadline = time.monotonic() + 10
        while len(received) <= len(data) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert Detection2DArray.deserialize(received[-1][0]).detections == []
        assert client.status("cam1").sessions == []
        sub.undeclare()
        rsub.close()
    finally:
        bridge.close()
        bridge.client.close()
        node.close()
        client.close()
        assert service.stop() == 0


