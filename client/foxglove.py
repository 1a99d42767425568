"""Foxglove's message schemas in their ROS 2 form: CDR in and out, and their definitions.

Two conventions of the drone world meet here. Video servers such as the MAVLink camera
manager of BlueOS put each encoded access unit on Zenoh as a CDR-encoded
``foxglove.CompressedVideo`` (``timestamp``, ``frame_id``, ``data``, ``format``), which the
service ingests next to its own frame messages; and Foxglove opens MCAP recordings whose
channels use its schemas (compressed image or video, image annotations), which
``arcf.adapters.record`` writes. Both need the same definitions: they are declared once, here, in
the ``foxglove_msgs`` ROS 2 package's text (the form Foxglove reads as ``ros2msg`` schemas),
and ``rosbags`` serialises and parses their CDR (:mod:`arcf.client.cdr`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cdr import MessageTypes

COMPRESSED_VIDEO = "foxglove_msgs/msg/CompressedVideo"
COMPRESSED_IMAGE = "foxglove_msgs/msg/CompressedImage"
IMAGE_ANNOTATIONS = "foxglove_msgs/msg/ImageAnnotations"

#: foxglove_msgs 3.x (the ROS 2 package of Foxglove's schemas), fields only
DEFINITIONS = {
    "foxglove_msgs/msg/Color": "float64 r\nfloat64 g\nfloat64 b\nfloat64 a\n",
    "foxglove_msgs/msg/Point2": "float64 x\nfloat64 y\n",
    COMPRESSED_VIDEO: "builtin_interfaces/Time timestamp\nstring frame_id\nuint8[] data\n"
                      "string format\n",
    COMPRESSED_IMAGE: "builtin_interfaces/Time timestamp\nstring frame_id\nuint8[] data\n"
                      "string format\n",
    "foxglove_msgs/msg/CircleAnnotation":
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nfloat64 diameter\n"
        "float64 thickness\nfoxglove_msgs/Color fill_color\nfoxglove_msgs/Color outline_color\n",
    "foxglove_msgs/msg/PointsAnnotation":
        "uint8 UNKNOWN=0\nuint8 POINTS=1\nuint8 LINE_LOOP=2\nuint8 LINE_STRIP=3\n"
        "uint8 LINE_LIST=4\n"
        "builtin_interfaces/Time timestamp\nuint8 type\nfoxglove_msgs/Point2[] points\n"
        "foxglove_msgs/Color outline_color\nfoxglove_msgs/Color[] outline_colors\n"
        "foxglove_msgs/Color fill_color\nfloat64 thickness\n",
    "foxglove_msgs/msg/TextAnnotation":
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nstring text\n"
        "float64 font_size\nfoxglove_msgs/Color text_color\n"
        "foxglove_msgs/Color background_color\n",
    IMAGE_ANNOTATIONS:
        "foxglove_msgs/CircleAnnotation[] circles\nfoxglove_msgs/PointsAnnotation[] points\n"
        "foxglove_msgs/TextAnnotation[] texts\n",
}


TYPES = MessageTypes(DEFINITIONS)
serialize = TYPES.serialize
deserialize = TYPES.deserialize
message = TYPES.message
time = TYPES.time
definition = TYPES.definition


@dataclass(frozen=True)
class VideoUnit:
    """One access unit of a ``foxglove.CompressedVideo`` message."""

    timestamp_ns: int
    frame_id: str
    data: bytes
    format: str


def parse_compressed_video(payload: bytes | memoryview) -> VideoUnit:
    """A CDR ``CompressedVideo``; raises ``ValueError`` on anything else (truncated, garbage)."""
    try:
        msg = deserialize(payload, COMPRESSED_VIDEO)
    except Exception as exc:  # rosbags raises several kinds on malformed CDR
        raise ValueError(f"not a CDR foxglove_msgs/CompressedVideo: {exc}") from exc
    return VideoUnit(int(msg.timestamp.sec) * 1_000_000_000 + int(msg.timestamp.nanosec),
                     str(msg.frame_id), bytes(msg.data), str(msg.format))


def compressed_video(unit: bytes, codec: str, timestamp_ns: int, frame_id: str = "") -> bytes:
    """One access unit as a CDR ``CompressedVideo`` (``codec``: ``h264`` or ``h265``)."""
    return serialize(message(COMPRESSED_VIDEO, timestamp=time(timestamp_ns), frame_id=frame_id,
                             data=np.frombuffer(unit, dtype=np.uint8), format=codec),
                     COMPRESSED_VIDEO)
