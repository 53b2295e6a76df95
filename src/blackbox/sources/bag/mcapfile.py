"""An MCAP file read front to back with the ``mcap`` library's stream reader.

Reading in file order (not through the summary at the end) replays a file cut off while
recording up to the last complete record. Channels map to topics: ``ros1`` messages with
``ros1msg`` schemas (the recorder's snapshots, ``mcap convert`` of ROS 1 bags), ``cdr``
messages with ``ros2msg``/``ros2idl`` schemas (rosbag2's MCAP storage) and ``json``.
A channel's ``callerid`` metadata, where a converter kept it, names its publisher.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from blackbox.sources.bag.records import BagCorrupt, Item, RecordedMessage, RecordedTopic

_SCHEMA_FORMATS = {"ros1msg": "msg", "ros2msg": "msg", "ros2idl": "idl",
                   "jsonschema": "jsonschema"}


class McapScanner:
    """Items of one MCAP file in file order; ``scan()`` raises :class:`BagCorrupt`."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size = path.stat().st_size
        self.bytes_read = 0

    def scan(self) -> Iterator[Item]:
        from mcap.records import Channel, Message, Schema
        from mcap.stream_reader import StreamReader

        schemas: dict[int, Schema] = {}
        topics: dict[int, RecordedTopic] = {}
        with self.path.open("rb") as fh:
            reader = StreamReader(fh, record_size_limit=1 << 32)
            records = reader.records
            good = 0
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    return
                except Exception as exc:
                    reason = str(exc) or type(exc).__name__
                    if fh.tell() >= self.size:
                        reason = f"file ends inside a record ({reason})"
                    raise BagCorrupt(str(self.path), good, reason) from None
                good = fh.tell()
                self.bytes_read = good
                if isinstance(record, Message):
                    topic = topics.get(record.channel_id)
                    if topic is None:
                        raise BagCorrupt(str(self.path), good, f"message on channel "
                                         f"{record.channel_id} that was never declared")
                    yield RecordedMessage(record.log_time, topic, record.data)
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel) and record.id not in topics:
                    topic = _topic(record, schemas.get(record.schema_id))
                    topics[record.id] = topic
                    yield topic


def _topic(channel: object, schema: object | None) -> RecordedTopic:
    from mcap.records import Channel, Schema

    assert isinstance(channel, Channel)
    encoding = channel.message_encoding
    type_name, definition, fmt = "", "", "msg"
    if isinstance(schema, Schema):
        type_name = schema.name
        fmt = _SCHEMA_FORMATS.get(schema.encoding, schema.encoding)
        definition = schema.data.decode("utf-8", "replace")
    return RecordedTopic(name=channel.topic, type=type_name, encoding=encoding,
                         definition=definition, definition_format=fmt,
                         md5sum=channel.metadata.get("md5sum", ""),
                         publisher=channel.metadata.get("callerid") or None)
