"""Decoding ROS 1 messages from the ``message_definition`` a publisher sends.

A TCPROS publisher states its message type and full definition in its connection header,
so the black box needs no message packages: types are registered into a ``rosbags`` type
store the first time a connection brings them.
"""

from __future__ import annotations

import threading
from typing import Any, cast

from rosbags.typesys import Stores, get_types_from_msg, get_typestore


def ros2_style_type(ros1_type: str) -> str:
    """``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image`` (the name rosbags uses)."""
    pkg, _, name = ros1_type.partition("/")
    return f"{pkg}/msg/{name}" if name and "/msg/" not in ros1_type else ros1_type


class MessageDecoder:
    """Decodes ROS 1 messages with types registered from connection headers."""

    def __init__(self) -> None:
        self._store = get_typestore(Stores.EMPTY)
        self._lock = threading.Lock()
        self._definitions: dict[str, str] = {}

    def register(self, ros1_type: str, definition: str) -> str:
        """Register ``ros1_type`` from its ``message_definition``; returns the rosbags name."""
        name = ros2_style_type(ros1_type)
        with self._lock:
            if self._definitions.get(name) == definition:
                return name
            types = get_types_from_msg(definition, name)
            known = self._store.fielddefs
            self._store.register({k: v for k, v in types.items() if k not in known})
            self._definitions[name] = definition
        return name

    def decode(self, data: bytes | bytearray | memoryview, name: str) -> Any:
        with self._lock:
            # rosbags reads any buffer; its annotation leaves out bytearray.
            return self._store.deserialize_ros1(cast(bytes, data), name)
