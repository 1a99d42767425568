"""ROS 2 message types beyond a distribution's standard ones: their CDR and their definitions.

``rosbags`` (a maintained pure-Python ROS 2 toolkit) carries each distribution's standard
messages, serialises and parses CDR and computes type hashes; packages it does not carry
(Foxglove's schemas, vision_msgs) are registered from their ``.msg`` text. A
:class:`MessageTypes` is one such set: ``arcf.client.foxglove`` and
``arcf.adapters.ros2_types`` each declare theirs with it.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

#: the ROS 2 distribution whose standard definitions (and so type hashes) are used
DISTRIBUTION = Stores.ROS2_JAZZY
_TIME = "builtin_interfaces/msg/Time"
_TIME_TEXT = "int32 sec\nuint32 nanosec\n"


class MessageTypes:
    """The distribution's types plus ``definitions`` (type name -> ``.msg`` text)."""

    def __init__(self, definitions: Mapping[str, str]) -> None:
        self.definitions = dict(definitions)

    @cached_property
    def store(self) -> Any:
        """The rosbags type store (built on first use, once)."""
        store = get_typestore(DISTRIBUTION)
        types: dict[str, Any] = {}
        for name, text in self.definitions.items():
            types.update(get_types_from_msg(text, name))
        store.register(types)
        return store

    def serialize(self, message: Any, ros_type: str) -> bytes:
        """CDR (little-endian, with its 4-byte encapsulation header), as ROS 2 sends it."""
        return bytes(self.store.serialize_cdr(message, ros_type))

    def deserialize(self, data: bytes | memoryview, ros_type: str) -> Any:
        return self.store.deserialize_cdr(bytes(data), ros_type)

    def message(self, ros_type: str, **fields: Any) -> Any:
        """An instance of a registered type (``message("std_msgs/msg/Header", ...)``)."""
        return self.store.types[ros_type](**fields)

    def time(self, ns: int) -> Any:
        """A ``builtin_interfaces/Time`` of nanoseconds since the Unix epoch."""
        return self.message(_TIME, sec=int(ns // 1_000_000_000),
                            nanosec=int(ns % 1_000_000_000))

    def definition(self, ros_type: str) -> str:
        """The type's full ``ros2msg`` text, its dependencies appended after ``MSG:``
        separators (the schema data of an MCAP channel that Foxglove decodes). Only types
        declared here, and ``builtin_interfaces/Time``, can be dependencies."""
        order: list[str] = []

        def visit(name: str) -> None:
            for line in self.definitions.get(name, "").splitlines():
                field_type = line.split()[0].rstrip("[]")
                if "/" in field_type and "=" not in line:
                    package, short = field_type.split("/")
                    dep = f"{package}/msg/{short}"
                    if dep not in order:
                        order.append(dep)
                        visit(dep)

        visit(ros_type)
        parts = [self.definitions[ros_type]]
        for dep in order:
            text = self.definitions.get(dep, _TIME_TEXT if dep == _TIME else None)
            if text is None:
                raise KeyError(f"no definition of {dep}")
            parts.append("=" * 80 + f"\nMSG: {dep.replace('/msg/', '/')}\n" + text)
        return "\n".join(parts)
