"""A ROS 1 bag (format 2.0) read front to back, record by record.

rosbags' own bag reader starts from the index at the end of the file, so a bag cut off
while recording (the usual bag after a crash) cannot be opened at all. Reading the records
in file order instead replays everything up to the damage and names the byte where it
starts. Connection records precede their messages (rosbag and rosbags write them into the
chunk of their first message), so each topic is announced before it is used.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from blackbox.sources.bag.records import BagCorrupt, Item, RecordedMessage, RecordedTopic

MAGIC = b"#ROSBAG V2.0\n"
OP_MESSAGE, OP_BAG_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
MAX_HEADER = 1 << 20
"""A record header longer than this is damage, not data (real headers are under 1 KiB
except connection records' message definitions, which stay far below)."""

_U32 = struct.Struct("<I")
_TIME = struct.Struct("<II")
_OP_MESSAGE_FIELD = b"\x04\x00\x00\x00op=\x02"
_CONN_FIELD = b"\x09\x00\x00\x00conn="
_TIME_FIELD = b"\x0d\x00\x00\x00time="
MESSAGE_HEADER_LEN = 3 * 4 + 4 + 9 + 13


def parse_header(buf: bytes | memoryview) -> dict[str, bytes]:
    """``len=field`` pairs of a record header, raising ``ValueError`` on a bad layout."""
    fields: dict[str, bytes] = {}
    view = memoryview(buf)
    pos, end = 0, len(view)
    while pos < end:
        if pos + 4 > end:
            raise ValueError("header field length cut off")
        (n,) = _U32.unpack_from(view, pos)
        pos += 4
        if pos + n > end:
            raise ValueError(f"header field of {n} bytes overruns its header")
        field = bytes(view[pos:pos + n])
        pos += n
        name, eq, value = field.partition(b"=")
        if not eq:
            raise ValueError(f"header field without '=': {field[:40]!r}")
        fields[name.decode("ascii", "replace")] = value
    return fields


def start_after_header(view: memoryview, pos: int) -> int:
    """End of the record at ``pos`` in ``view`` (its header length already fits)."""
    hlen: int = _U32.unpack_from(view, pos)[0]
    dlen: int = _U32.unpack_from(view, pos + 4 + hlen)[0]
    return pos + 8 + hlen + dlen


class Ros1BagScanner:
    """Items of one bag in file order; ``scan()`` raises :class:`BagCorrupt` at damage."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size = path.stat().st_size
        self._conns: dict[int, RecordedTopic] = {}
        self.bytes_read = 0

    def scan(self) -> Iterator[Item]:
        with self.path.open("rb") as fh:
            if fh.read(len(MAGIC)) != MAGIC:
                raise BagCorrupt(str(self.path), 0, "not a ROS 1 bag (no '#ROSBAG V2.0' line)")
            offset = len(MAGIC)
            while offset < self.size:
                op, header, data, complete = self._record(fh, offset)
                if complete:
                    yield from self._handle(op, header, data, offset)
                else:
                    yield from self._chunk(header, data, offset, complete=False)
                offset = fh.tell()
                self.bytes_read = offset

    def _record(self, fh: BinaryIO, offset: int
                ) -> tuple[int, dict[str, bytes], bytes, bool]:
        """One record at ``offset``: op, header, data and whether the data is complete
        (only a chunk may be cut off: its complete messages are still worth reading)."""
        head = fh.read(4)
        if len(head) < 4:
            self._cut(offset, "record header length cut off")
        (hlen,) = _U32.unpack(head)
        if hlen > MAX_HEADER or offset + 4 + hlen > self.size:
            self._cut(offset, f"record header of {hlen:,} bytes does not fit in the file")
        try:
            header = parse_header(fh.read(hlen))
        except ValueError as exc:
            raise BagCorrupt(str(self.path), offset, f"bad record header: {exc}") from None
        op_b = header.get("op")
        if op_b is None or len(op_b) != 1:
            raise BagCorrupt(str(self.path), offset, "record header has no 'op' field")
        dlen_b = fh.read(4)
        if len(dlen_b) < 4:
            self._cut(offset, "record data length cut off")
        (dlen,) = _U32.unpack(dlen_b)
        complete = offset + 8 + hlen + dlen <= self.size
        if not complete and op_b[0] != OP_CHUNK:
            self._cut(offset, f"record of {8 + hlen + dlen:,} bytes runs past the end of "
                              f"the file ({self.size:,} bytes)")
        return op_b[0], header, fh.read(dlen), complete

    def _cut(self, offset: int, reason: str) -> None:
        raise BagCorrupt(str(self.path), offset, reason)

    def _handle(self, op: int, header: dict[str, bytes], data: bytes,
                offset: int) -> Iterator[Item]:
        if op == OP_CHUNK:
            yield from self._chunk(header, data, offset)
        elif op == OP_CONNECTION:
            topic = self._connection(header, data, offset)
            if topic is not None:
                yield topic
        elif op == OP_MESSAGE:
            yield self._message(header, data, offset)
        elif op not in (OP_BAG_HEADER, OP_INDEX, OP_CHUNK_INFO):
            raise BagCorrupt(str(self.path), offset, f"unknown record op {op:#04x}")

    def _chunk(self, header: dict[str, bytes], data: bytes, offset: int,
               complete: bool = True) -> Iterator[Item]:
        """The records of a chunk; of a chunk the file ends inside, the complete ones
        before the cut (decompressed as far as the data goes), then :class:`BagCorrupt`."""
        compression = header.get("compression", b"none").decode("ascii", "replace")
        try:
            if compression == "none":
                raw = data
            elif compression == "bz2":
                raw = bz2.BZ2Decompressor().decompress(data)
            elif compression == "lz4":
                import lz4.frame  # type: ignore[import-untyped]

                raw = lz4.frame.LZ4FrameDecompressor().decompress(data)
            else:
                raise ValueError(f"unknown chunk compression {compression!r}")
        except Exception as exc:
            raise BagCorrupt(str(self.path), offset, f"chunk does not decompress: {exc}"
                             ) from None
        if not complete:
            yield from self._chunk_records(memoryview(raw), offset, stop_at_cut=True)
            raise BagCorrupt(str(self.path), offset,
                             f"the file ({self.size:,} bytes) ends inside this chunk; its "
                             "complete messages before the cut were read")
        yield from self._chunk_records(memoryview(raw), offset)

    def _chunk_records(self, view: memoryview, offset: int,
                       stop_at_cut: bool = False) -> Iterator[Item]:
        pos, end = 0, len(view)
        while pos < end:
            if stop_at_cut and (pos + 8 > end or pos + 8 + _U32.unpack_from(view, pos)[0] > end
                                or start_after_header(view, pos) > end):
                return
            message = self._fast_message(view, pos, end)
            if message is not None:
                yield message[0]
                pos = message[1]
                continue
            try:
                if pos + 4 > end:
                    raise ValueError("record cut off")
                (hlen,) = _U32.unpack_from(view, pos)
                if pos + 8 + hlen > end:
                    raise ValueError(f"record header of {hlen:,} bytes overruns the chunk")
                header_in = parse_header(view[pos + 4:pos + 4 + hlen])
                (dlen,) = _U32.unpack_from(view, pos + 4 + hlen)
                start = pos + 8 + hlen
                if start + dlen > end:
                    raise ValueError(f"record of {dlen:,} data bytes overruns the chunk")
                op_b = header_in.get("op", b"")
                if len(op_b) != 1:
                    raise ValueError("record header has no 'op' field")
            except ValueError as exc:
                raise BagCorrupt(str(self.path), offset,
                                 f"chunk record at {pos:,} bytes into the chunk: {exc}"
                                 ) from None
            body = view[start:start + dlen]
            if op_b[0] == OP_MESSAGE:
                yield self._message(header_in, body, offset)
            elif op_b[0] == OP_CONNECTION:
                topic = self._connection(header_in, bytes(body), offset)
                if topic is not None:
                    yield topic
            pos = start + dlen

    def _fast_message(self, view: memoryview, pos: int, end: int
                      ) -> tuple[RecordedMessage, int] | None:
        """A message record with the usual three header fields (op, conn, time) in any
        order, read without building a header dict; ``None`` for anything else."""
        if pos + 8 + MESSAGE_HEADER_LEN > end or \
                _U32.unpack_from(view, pos)[0] != MESSAGE_HEADER_LEN:
            return None
        head = view[pos + 4:pos + 4 + MESSAGE_HEADER_LEN].tobytes()
        c = head.find(_CONN_FIELD)
        t = head.find(_TIME_FIELD)
        if c < 0 or t < 0 or _OP_MESSAGE_FIELD not in head:
            return None
        (conn,) = _U32.unpack_from(head, c + len(_CONN_FIELD))
        topic = self._conns.get(conn)
        if topic is None:
            return None
        sec, nsec = _TIME.unpack_from(head, t + len(_TIME_FIELD))
        start = pos + 8 + MESSAGE_HEADER_LEN
        (dlen,) = _U32.unpack_from(view, start - 4)
        if start + dlen > end:
            return None
        return (RecordedMessage(sec * 1_000_000_000 + nsec, topic, view[start:start + dlen]),
                start + dlen)

    def _connection(self, header: dict[str, bytes], data: bytes,
                    offset: int) -> RecordedTopic | None:
        try:
            (conn,) = _U32.unpack(header["conn"])
            fields = parse_header(data)
            name = header["topic"].decode()
        except (KeyError, ValueError, struct.error) as exc:
            raise BagCorrupt(str(self.path), offset, f"bad connection record: {exc!r}"
                             ) from None
        if conn in self._conns:
            return None
        callerid = fields.get("callerid", b"").decode() or None
        topic = RecordedTopic(
            name=name, type=fields.get("type", b"").decode(), encoding="ros1",
            definition=fields.get("message_definition", b"").decode("utf-8", "replace"),
            definition_format="msg", md5sum=fields.get("md5sum", b"").decode(),
            publisher=callerid)
        self._conns[conn] = topic
        return topic

    def _message(self, header: dict[str, bytes], data: bytes | memoryview,
                 offset: int) -> RecordedMessage:
        try:
            (conn,) = _U32.unpack(header["conn"])
            sec, nsec = _TIME.unpack(header["time"])
            topic = self._conns[conn]
        except (KeyError, struct.error) as exc:
            raise BagCorrupt(str(self.path), offset, f"bad message record: {exc!r}") from None
        return RecordedMessage(sec * 1_000_000_000 + nsec, topic, data)
