"""The TCPROS wire format: message framing and connection headers, with no sockets kept.

Every TCPROS message and every connection header is a 4-byte little-endian length followed
by that many bytes; a header's bytes are fields, each a 4-byte length and ``key=value``.
The black box speaks this from both ends (it subscribes to topics by hand and publishes
``/diagnostics``), so the codec lives apart from the subscriber and the publisher that use
it: neither imports the other to frame a message.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Mapping

from blackbox.errors import BlackBoxError

MAX_HEADER_BYTES = 1024 * 1024
LENGTH = struct.Struct("<I")
"""The length prefix of a message, a header and each header field."""


class HeaderError(BlackBoxError):
    """A connection header that is not TCPROS."""


def encode_header(fields: Mapping[str, str]) -> bytes:
    """A TCPROS header: total length, then per field a length and ``key=value``."""
    body = b"".join(LENGTH.pack(len(kv)) + kv
                    for kv in (f"{k}={v}".encode() for k, v in fields.items()))
    return LENGTH.pack(len(body)) + body


def decode_header(body: bytes) -> dict[str, str]:
    """The fields of a header body (without its total length prefix)."""
    fields: dict[str, str] = {}
    pos, n = 0, len(body)
    while pos < n:
        if pos + 4 > n:
            raise HeaderError(f"truncated field length at byte {pos}")
        (size,) = LENGTH.unpack_from(body, pos)
        pos += 4
        if size > n - pos:
            raise HeaderError(f"field of {size} bytes at byte {pos} overruns the "
                              f"{n}-byte header")
        raw = body[pos:pos + size]
        pos += size
        key, sep, value = raw.partition(b"=")
        if not sep:
            raise HeaderError(f"field without '=' at byte {pos - size}: {raw[:40]!r}")
        try:
            fields[key.decode()] = value.decode()
        except UnicodeDecodeError:
            raise HeaderError(f"field at byte {pos - size} is not UTF-8") from None
    return fields


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        k = sock.recv_into(view[got:])
        if k == 0:
            raise ConnectionError(f"closed by the publisher after {got} of {n} header bytes")
        got += k
    return bytes(buf)


def read_header(sock: socket.socket, cap: int, peer: str = "") -> dict[str, str]:
    """One length-prefixed TCPROS connection header from a blocking ``sock``, refused
    (:class:`HeaderError`) when its length prefix says more than ``cap`` bytes."""
    (size,) = LENGTH.unpack(_recv_exact(sock, 4))
    if size > cap:
        origin = f" from {peer}" if peer else ""
        raise HeaderError(f"connection header of {size} bytes{origin} exceeds {cap} bytes")
    return decode_header(_recv_exact(sock, size))


def frame(message: bytes | bytearray | memoryview) -> bytes:
    """One message as it goes on the wire: its length, then its bytes."""
    return LENGTH.pack(len(message)) + bytes(message)
