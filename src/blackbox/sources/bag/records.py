"""What every bag reader yields: the topics it learns and the messages it reads, in file order.

A reader announces a topic (or a new publisher of it) before that topic's first message,
so a replay can build the recorded graph as it goes, without reading the file twice. A
reader that meets a cut-off or damaged record raises :class:`BagCorrupt` with the byte
offset, after yielding everything before it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from blackbox.errors import BlackBoxError


@dataclass(frozen=True, slots=True, eq=False)
class RecordedTopic:
    """A topic as the file describes it.

    ``encoding`` is the serialization of its messages: ``ros1``, ``cdr`` (ROS 2) or
    ``json``. ``definition`` is the message definition the file carries (empty if none);
    ``definition_format`` says its language: ``msg`` (ROS 1 ``message_definition`` or ROS 2
    ``ros2msg``, both ``.msg`` text with ``MSG:`` sections), ``idl`` or ``jsonschema``.
    ``publisher`` is the node that published it where the file records one (ROS 1 bags:
    the connection's ``callerid``), else ``None``. Each connection or channel of a file is
    one object, compared by identity (two connections may describe the same topic).
    """

    name: str
    type: str
    encoding: str
    definition: str = ""
    definition_format: str = "msg"
    md5sum: str = ""
    publisher: str | None = None


class RecordedMessage(NamedTuple):
    """One message: the time it was recorded (nanoseconds since the epoch), its topic
    (connection) and its serialized bytes. A tuple: replay makes millions of them."""

    time_ns: int
    topic: RecordedTopic
    data: bytes | memoryview


class BagCorrupt(BlackBoxError):
    """A record the reader cannot read: ``offset`` is the byte where it starts (``None``
    for storage without meaningful offsets, such as SQLite)."""

    def __init__(self, path: str, offset: int | None, reason: str) -> None:
        where = f"at byte {offset:,}" if offset is not None else "while reading"
        super().__init__(f"{path}: corrupt or truncated {where}: {reason}")
        self.path = path
        self.offset = offset
        self.reason = reason


Item = RecordedTopic | RecordedMessage
