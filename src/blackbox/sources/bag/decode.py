"""Turning a recorded topic's bytes into the values observers read, with ``rosbags``.

Each topic gets its decoder from the definition the file carries (ROS 1 connection
headers, MCAP schemas, rosbag2 ≥ Iron) registered in a type store of its own, so two
topics with different versions of one type never clash. A file without a definition falls
back to rosbags' built-in store of its ROS version. A topic whose type neither provides is
*unknown*: its messages still arrive (rate, size, age of arrival), their ``value`` is
``None``, and the replay reports it once per topic.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from functools import cache
from typing import Any

from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from blackbox.errors import BlackBoxError
from blackbox.events import TopicSchema
from blackbox.sources.bag.records import RecordedTopic

Decoder = Callable[[bytes | memoryview], Any]


class UnknownBagType(BlackBoxError):
    """The topic's type cannot be decoded; the message says why."""


def store_name(type_name: str) -> str:
    """``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image`` (the spelling rosbags keys on)."""
    parts = type_name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else type_name


@cache
def _builtin(store: Stores) -> Typestore:
    return get_typestore(store)


def decoder_for(topic: RecordedTopic) -> Decoder:
    """A function decoding one message of ``topic``; raises :class:`UnknownBagType`."""
    if topic.encoding == "json":
        return _json
    if topic.encoding not in ("ros1", "cdr"):
        raise UnknownBagType(f"message encoding {topic.encoding!r} is not ros1, cdr or json")
    if not topic.type:
        raise UnknownBagType("no type recorded")
    name = store_name(topic.type)
    store = _store_with_definition(topic, name) if topic.definition.strip() else None
    if store is None:
        store = _builtin(Stores.ROS1_NOETIC if topic.encoding == "ros1" else Stores.LATEST)
        if name not in store.types:
            raise UnknownBagType(f"type {topic.type} has no definition in the file and is not "
                              "in rosbags' built-in type store")
    if topic.encoding == "ros1":
        deserialize_ros1 = store.deserialize_ros1
        return lambda data: deserialize_ros1(data, name)
    deserialize_cdr = store.deserialize_cdr
    return lambda data: deserialize_cdr(data, name)


def _store_with_definition(topic: RecordedTopic, name: str) -> Typestore:
    store = get_typestore(Stores.EMPTY)
    try:
        if topic.definition_format == "idl":
            types = get_types_from_idl(topic.definition)
        else:
            types = get_types_from_msg(topic.definition, name)
        store.register(types)
    except Exception as exc:  # rosbags raises several parser exception types
        raise UnknownBagType(f"definition of {topic.type} does not parse: {exc}") from None
    if name not in store.types:
        raise UnknownBagType(f"definition does not define {topic.type}")
    return store


def _json(data: bytes | memoryview) -> Any:
    return json.loads(bytes(data))


def schema_of(topic: RecordedTopic) -> TopicSchema | None:
    """How to write the topic back out (recorder snapshots): ROS 1 topics only."""
    if topic.encoding == "ros1" and topic.definition:
        return TopicSchema(topic.name, topic.type, "ros1", topic.definition, topic.md5sum)
    if topic.encoding == "json":
        return TopicSchema(topic.name, topic.type, "json", topic.definition)
    return None
