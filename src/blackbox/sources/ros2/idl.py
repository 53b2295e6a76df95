"""Cyclone DDS reader types for ROS 2 messages, generated from the ``rosbags`` type store.

Cyclone checks every received sample against its reader's type, so a reader needs an
``IdlStruct`` laid out exactly like the ROS 2 message. Rather than hand-write message
classes, :class:`IdlTypes` builds them on demand from the type store's field definitions
(``Stores.ROS2_KILTED`` by default, 163 types), nested types and arrays included, under
the DDS type name a ROS 2 middleware uses (``std_msgs::msg::dds_::String_``).
"""

from __future__ import annotations

from typing import Any

from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as _idl_types
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from blackbox.errors import BlackBoxError

__all__ = ["IdlTypes", "UnknownRos2Type", "dds_type_name", "ros_type_name"]

t: Any = _idl_types  # generic IDL type constructors (untyped for mypy)

_BASE: dict[str, Any] = {
    "bool": bool, "byte": t.uint8, "char": t.uint8, "int8": t.int8, "uint8": t.uint8,
    "int16": t.int16, "uint16": t.uint16, "int32": t.int32, "uint32": t.uint32,
    "int64": t.int64, "uint64": t.uint64, "float32": t.float32, "float64": t.float64,
}

_NODE_BASE, _NODE_NAME, _NODE_ARRAY, _NODE_SEQUENCE = 1, 2, 3, 4


class UnknownRos2Type(BlackBoxError, LookupError):
    """The type store has no definition of a message type (or of one of its fields)."""


def ros_type_name(dds_name: str) -> str | None:
    """``std_msgs::msg::dds_::String_`` -> ``std_msgs/msg/String``; ``None`` if not ROS 2."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        return None
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def dds_type_name(ros_name: str) -> str:
    """``std_msgs/msg/String`` -> ``std_msgs::msg::dds_::String_``."""
    pkg, kind, name = ros_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


class IdlTypes:
    """IdlStructs for ROS 2 message types, built once per type name."""

    def __init__(self, store: Typestore | None = None) -> None:
        self.store = store if store is not None else get_typestore(Stores.ROS2_KILTED)
        self._made: dict[str, type[IdlStruct]] = {}

    def knows(self, ros_name: str) -> bool:
        return ros_name in self.store.fielddefs

    def struct(self, ros_name: str) -> type[IdlStruct]:
        """The reader type of ``ros_name`` (``pkg/msg/Type``); ``UnknownRos2Type`` if unknown."""
        made = self._made.get(ros_name)
        if made is None:
            made = self._made[ros_name] = self._make(ros_name)
        return made

    def _make(self, ros_name: str) -> type[IdlStruct]:
        try:
            _, fields = self.store.fielddefs[ros_name]
        except KeyError:
            raise UnknownRos2Type(ros_name) from None
        annotations = {f"{name}": self._field(desc) for name, desc in fields}
        class_name = ros_name.replace("/", "_")
        try:
            return make_idl_struct(class_name, dds_type_name(ros_name), annotations)
        except Exception as exc:  # a definition Cyclone's IDL layer cannot express
            raise UnknownRos2Type(f"{ros_name}: {exc}") from exc

    def _field(self, desc: tuple[Any, Any]) -> Any:
        node, detail = desc
        if node == _NODE_BASE:
            name, bound = detail
            if name == "string":
                return t.bounded_str[bound] if bound else str
            if name == "wstring":
                raise UnknownRos2Type("wstring fields are not supported")
            return _BASE[name]
        if node == _NODE_NAME:
            return self.struct(detail)
        if node == _NODE_ARRAY:
            sub, length = detail
            return t.array[self._field(sub), length]
        if node == _NODE_SEQUENCE:
            sub, bound = detail
            return t.sequence[self._field(sub), bound] if bound else t.sequence[self._field(sub)]
        raise UnknownRos2Type(f"field kind {node!r}")
