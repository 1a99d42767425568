"""ROS 2 message types for the ROS 2 adapter: definitions, CDR and type hashes from ``rosbags``.

``rosbags`` (a maintained pure-Python ROS 2 toolkit on PyPI) carries the standard messages of
each ROS 2 distribution (Jazzy's are used, :mod:`arcf.client.cdr`), serialises and parses CDR, and
computes the RIHS01 type hashes that ``rmw_zenoh`` puts in every key. ``vision_msgs`` is not
among its standard messages, so its definitions (vision_msgs 4.x, as shipped with Humble,
Jazzy and later) are registered here from their ``.msg`` text.
"""

from __future__ import annotations

from typing import Any

from arcf.client.cdr import MessageTypes

COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
DETECTION_2D_ARRAY = "vision_msgs/msg/Detection2DArray"
DETECTION_2D = "vision_msgs/msg/Detection2D"
#: a standard message of the distribution (ROS's own health reports, ``/diagnostics``)
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"

#: vision_msgs 4.x definitions (fields only; comments do not enter the type hash)
VISION_MSGS = {
    "vision_msgs/msg/Point2D": "float64 x\nfloat64 y\n",
    "vision_msgs/msg/Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "vision_msgs/msg/BoundingBox2D":
        "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose":
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n",
    DETECTION_2D: "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
                  "vision_msgs/BoundingBox2D bbox\nstring id\n",
    DETECTION_2D_ARRAY: "std_msgs/Header header\nvision_msgs/Detection2D[] detections\n",
}


TYPES = MessageTypes(VISION_MSGS)
serialize = TYPES.serialize
deserialize = TYPES.deserialize
message = TYPES.message


def typestore() -> Any:
    """The distribution's types plus vision_msgs (built once per process)."""
    return TYPES.store


def dds_type_name(ros_type: str) -> str:
    """``sensor_msgs/msg/CompressedImage`` -> ``sensor_msgs::msg::dds_::CompressedImage_``,
    the name rmw_zenoh (like the DDS RMWs) uses on the wire."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(ros_type: str) -> str:
    """The type's RIHS01 hash (``RIHS01_<64 hex>``)."""
    return str(typestore().hash_rihs01(ros_type))
