"""TCPROS subscriber connections made by hand, one per publisher, never registered.

The black box asks a publisher directly for a connection (``requestTopic`` on its slave
API), so the master never lists it as a subscriber. Every connection is read by one
selector thread. Topics observed for timing only are read into a shared scratch buffer and
never decoded: per message the cost is a length prefix and a few counters. Topics whose
values are observed keep their bytes and decode lazily with ``rosbags`` from the
``message_definition`` the publisher sent in its connection header.

Each wake-up reads everything the socket holds (up to 256 KiB) in one ``recvmsg`` and splits
every message out of that one buffer; the arrivals of one read are handed on together, so
the hand-over lock is taken once per read, not once per message. Arrival times come from the
kernel (``SO_TIMESTAMPNS``: when the last segment of the read reached the socket), not from
when Python got round to reading, so a reader that is late by some milliseconds does not
distort inter-arrival times; where the kernel gives no stamp, the wall clock at the read is
used.

Whatever a publisher sends, the black box keeps going: malformed headers, absurd length
prefixes (beyond a per-topic cap) and silent dead peers close that one connection with a
reason, and the connection is retried with backoff.
"""

from __future__ import annotations

import contextlib
import logging
import mmap
import selectors
import socket
import struct
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from blackbox.events import ArrivalBatch, MessageArrival, TopicSchema
from blackbox.sources.ros1.callerid import unique_caller_id
from blackbox.sources.ros1.master import Report, RosApi, RosApiError

if TYPE_CHECKING:
    from blackbox.sources.ros1.readers import ReaderProcesses

log = logging.getLogger("blackbox.sources.ros1")

DEFAULT_MAX_MESSAGE_BYTES = 64 * 1024 * 1024
MAX_HEADER_BYTES = 1024 * 1024
_LEN = struct.Struct("<I")
_SCRATCH_BYTES = 256 * 1024
_SKIP_BYTES = 4 * 1024 * 1024
_LOWAT_CAP = _SKIP_BYTES
_READS_PER_WAKEUP = 16
# Linux: SO_TIMESTAMPNS (== SCM_TIMESTAMPNS) delivers a struct timespec per recvmsg.
SO_TIMESTAMPNS: int | None = getattr(socket, "SO_TIMESTAMPNS", 35 if hasattr(socket, "AF_NETLINK")
                                     else None)
_TIMESPEC = struct.Struct("@qq")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0


class HeaderError(Exception):
    """A connection header that is not TCPROS."""


def encode_header(fields: Mapping[str, str]) -> bytes:
    """A TCPROS header: total length, then per field a length and ``key=value``."""
    body = b"".join(_LEN.pack(len(kv)) + kv
                    for kv in (f"{k}={v}".encode() for k, v in fields.items()))
    return _LEN.pack(len(body)) + body


def decode_header(body: bytes) -> dict[str, str]:
    """The fields of a header body (without its total length prefix)."""
    fields: dict[str, str] = {}
    pos, n = 0, len(body)
    while pos < n:
        if pos + 4 > n:
            raise HeaderError(f"truncated field length at byte {pos}")
        (size,) = _LEN.unpack_from(body, pos)
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
    (size,) = _LEN.unpack(_recv_exact(sock, 4))
    if size > cap:
        origin = f" from {peer}" if peer else ""
        raise HeaderError(f"connection header of {size} bytes{origin} exceeds {cap} bytes")
    return decode_header(_recv_exact(sock, size))


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


@dataclass(frozen=True, slots=True)
class StreamKey:
    topic: str
    publisher: str


class _Stream:
    """Reading state of one established connection."""

    __slots__ = ("body", "closed", "decode_as", "key", "last_rx", "lenbuf", "lenfill",
                 "lowat", "max_bytes", "messages", "pending", "pending_bytes", "publisher",
                 "remaining", "size", "sock", "topic")

    def __init__(self, key: StreamKey, sock: socket.socket, max_bytes: int,
                 decode_as: str | None) -> None:
        self.key = key
        self.topic = key.topic
        self.publisher = key.publisher
        self.sock = sock
        self.max_bytes = max_bytes
        self.decode_as = decode_as
        self.lenbuf = bytearray(4)
        self.lenfill = 0
        self.remaining = -1  # -1: reading a length prefix
        self.size = 0
        self.body: bytearray | None = None
        self.last_rx = time.monotonic()
        self.messages = 0
        self.closed = False
        self.lowat = 1
        self.pending = 0  # compact: timing-only messages completed in the current receive
        self.pending_bytes = 0


Arrivals = list[MessageArrival | ArrivalBatch]
"""What one wake-up of a reader hands on."""


class TcprosReader:
    """One thread reading every TCPROS connection through a selector."""

    def __init__(self, on_message: Callable[[MessageArrival], None],
                 on_closed: Callable[[StreamKey, str, int], None],
                 on_first: Callable[[StreamKey], None], decoder: MessageDecoder,
                 on_batch: Callable[[Arrivals], None] | None = None,
                 compact: bool = False, hand_over: float = 0.0,
                 coalesce: float = 0.0) -> None:
        """``on_batch`` receives the arrivals of one wake-up together (preferred, one
        call per wake-up); without it ``on_message`` is called per message.

        ``compact``: the messages of a timing-only connection that one receive got are
        handed on as one :class:`ArrivalBatch` (no object per message); otherwise as
        one :class:`MessageArrival` each (``on_message`` always gets arrivals).

        ``hand_over``: hand on at most every this many seconds what the wake-ups since
        read (fewer wake-ups of whoever takes them; arrival times are unchanged).

        ``coalesce``: at least this many seconds between two wake-ups (a quiet reader is
        woken at once, a busy one waits out the rest), so a fast topic's messages are
        read several at a time instead of one wake-up each. Arrival times are the
        kernel's per receive, so messages of one connection that arrive within
        ``coalesce`` of each other share the time of the last of them (a 5 kHz topic
        with 1 ms: five per receive, periods of 1 ms and four of 0, the mean unchanged);
        topics slower than ``1 / coalesce`` keep exact times."""
        self._on_message = on_message
        self._on_batch = on_batch
        self._compact = compact
        self._hand_over_every = hand_over
        self._coalesce = coalesce
        self._held: Arrivals = []
        self._closed_notes: list[tuple[StreamKey, str, int]] = []
        self._on_closed = on_closed
        self._on_first = on_first
        self._decoder = decoder
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._selector.register(self._wake_r, selectors.EVENT_READ, None)
        self._pending: list[_Stream] = []
        self._drop: list[tuple[StreamKey, str]] = []
        self._lock = threading.Lock()
        self._streams: dict[StreamKey, _Stream] = {}
        self._scratch = bytearray(_SCRATCH_BYTES)
        self._view = memoryview(self._scratch)
        # never written (MSG_TRUNC), so an anonymous mapping costs no memory
        self._skip_map = mmap.mmap(-1, _SKIP_BYTES)
        self._skip = memoryview(self._skip_map)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ros1-tcpros", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def add(self, key: StreamKey, sock: socket.socket, max_bytes: int,
            decode_as: str | None) -> None:
        sock.setblocking(False)
        if SO_TIMESTAMPNS is not None and _ANCILLARY:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        with self._lock:
            self._pending.append(_Stream(key, sock, max_bytes, decode_as))
        self._wake()

    def drop(self, key: StreamKey, reason: str) -> None:
        """Close ``key``'s connection from another thread (half-open, lost interest)."""
        with self._lock:
            self._drop.append((key, reason))
        self._wake()

    def idle_seconds(self) -> dict[StreamKey, float]:
        now = time.monotonic()
        return {k: now - s.last_rx for k, s in list(self._streams.items())}

    def close(self) -> None:
        self._stop.set()
        self._wake()
        self._thread.join(timeout=2.0)
        for s in list(self._streams.values()):
            with contextlib.suppress(OSError):
                s.sock.close()
        self._streams.clear()
        self._selector.close()
        self._skip.release()
        self._skip_map.close()
        self._wake_r.close()
        self._wake_w.close()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")

    def _run(self) -> None:
        select = self._selector.select
        clock = time.monotonic
        every = self._hand_over_every
        coalesce = self._coalesce
        stop = self._stop
        handed = woke = 0.0
        while not stop.is_set():
            if coalesce > 0:  # only a busy reader waits: a quiet one is woken at once
                rest = woke + coalesce - clock()
                if rest > 0:
                    time.sleep(rest)
            timeout = 1.0
            if self._held and every > 0:
                timeout = max(0.0, handed + every - clock())
            ready = select(timeout=timeout)
            woke = clock()
            for sel_key, _ in ready:
                stream = sel_key.data
                try:
                    if stream is None:
                        self._service_wakeup()
                    elif not stream.closed:
                        self._read(stream)
                except Exception as exc:  # one bad connection must not stop the reader
                    log.exception("TCPROS reader")
                    if stream is not None and not stream.closed:
                        self._close(stream, f"internal error while reading: {exc!r}")
            if self._held and (every <= 0 or woke - handed >= every or self._closed_notes):
                handed = woke
                self._hand_over()
            while self._closed_notes:
                self._on_closed(*self._closed_notes.pop(0))
        if self._held:
            self._hand_over()

    def _hand_over(self) -> None:
        batch, self._held = self._held, []
        if self._on_batch is not None:
            self._on_batch(batch)
            return
        for item in batch:
            if type(item) is ArrivalBatch:
                for arrival in item.arrivals():
                    self._on_message(arrival)
            else:
                self._on_message(cast(MessageArrival, item))

    def _service_wakeup(self) -> None:
        with contextlib.suppress(OSError):
            while self._wake_r.recv(4096):
                pass
        with self._lock:
            pending, self._pending = self._pending, []
            drops, self._drop = self._drop, []
        for stream in pending:
            old = self._streams.get(stream.key)
            if old is not None:
                self._close(old, "replaced by a new connection", notify=False)
            self._streams[stream.key] = stream
            self._selector.register(stream.sock, selectors.EVENT_READ, stream)
        for key, reason in drops:
            dropped = self._streams.get(key)
            if dropped is not None:
                self._close(dropped, reason)

    def _close(self, stream: _Stream, reason: str, notify: bool = True) -> None:
        stream.closed = True
        with contextlib.suppress(KeyError, ValueError, OSError):
            self._selector.unregister(stream.sock)
        with contextlib.suppress(OSError):
            stream.sock.close()
        if self._streams.get(stream.key) is stream:
            del self._streams[stream.key]
        if notify:  # told after the round's arrivals are handed on: they came first
            self._closed_notes.append((stream.key, reason, stream.messages))

    def _recv(self, s: _Stream, into: memoryview, flags: int) -> tuple[int, float] | None:
        """Bytes read (or, with ``MSG_TRUNC``, dropped) and their kernel time; ``None``
        when nothing is there or the connection ended (then it is closed)."""
        try:
            n, ancillary, _, _ = s.sock.recvmsg_into((into,), _ANCILLARY, flags)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError as exc:
            self._close(s, f"connection error: {exc}")
            return None
        if n == 0:
            self._close(s, "publisher closed the connection")
            return None
        return n, kernel_time(ancillary)

    def _read(self, s: _Stream) -> None:
        view = self._view
        batch = self._held
        try:
            for _ in range(_READS_PER_WAKEUP):
                if s.body is None and s.remaining > 0:
                    # the body of a timing-only message: the kernel drops it uncopied
                    got = self._recv(s, self._skip[:min(s.remaining, _SKIP_BYTES)],
                                     socket.MSG_TRUNC)
                    if got is None:
                        break
                    n, now = got
                    s.remaining -= n
                    if s.remaining == 0:
                        self._complete(s, now, batch)
                        if s.pending:
                            self._flush(s, now, batch)
                    continue
                got = self._recv(s, view, 0)
                if got is None:
                    break
                n, now = got
                self._split(s, n, now, batch)
                if s.pending:
                    self._flush(s, now, batch)
                if s.closed or n < len(view):
                    break
        finally:
            if not s.closed:
                s.last_rx = time.monotonic()
                self._wake_at(s)

    @staticmethod
    def _flush(s: _Stream, now: float, batch: Arrivals) -> None:
        batch.append(ArrivalBatch(now, s.topic, s.publisher, s.pending, s.pending_bytes))
        s.pending = 0
        s.pending_bytes = 0

    def _wake_at(self, s: _Stream) -> None:
        """Be woken only once the rest of the current message is there (``SO_RCVLOWAT``):
        a 900 kB camera image then costs one or two wake-ups, not one per segment."""
        want = min(s.remaining, _LOWAT_CAP) if s.remaining > 0 else \
            (4 - s.lenfill if s.lenfill else 1)
        if want != s.lowat:
            with contextlib.suppress(OSError):
                s.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVLOWAT, want)
                s.lowat = want

    def _complete(self, s: _Stream, now: float, batch: Arrivals) -> None:
        s.remaining = -1
        s.messages += 1
        if s.messages == 1:
            self._on_first(s.key)
        if s.body is not None:
            batch.append(self._decodable(s, now))
        elif self._compact:
            s.pending += 1
            s.pending_bytes += s.size
        else:
            batch.append(MessageArrival(now, s.topic, s.publisher, s.size))

    def _split(self, s: _Stream, n: int, now: float, batch: Arrivals) -> None:
        view = self._view
        pos = 0
        if self._compact and s.decode_as is None and s.remaining < 0 and not s.lenfill:
            pos = self._count_whole(s, n)
        while pos < n:
            if s.remaining < 0:
                if s.lenfill == 0 and n - pos >= 4:
                    (size,) = _LEN.unpack_from(view, pos)
                    pos += 4
                else:
                    take = min(4 - s.lenfill, n - pos)
                    s.lenbuf[s.lenfill:s.lenfill + take] = view[pos:pos + take]
                    s.lenfill += take
                    pos += take
                    if s.lenfill < 4:
                        break
                    (size,) = _LEN.unpack_from(s.lenbuf, 0)
                    s.lenfill = 0
                if size > s.max_bytes:
                    self._close(s, f"message length prefix of {size} bytes exceeds the cap "
                                   f"of {s.max_bytes} bytes for {s.topic} (garbage or "
                                   f"oversized message)")
                    return
                s.size = size
                s.remaining = size
                if s.decode_as is not None:
                    s.body = bytearray(size)
                if size:
                    continue
            else:
                take = s.remaining if s.remaining < n - pos else n - pos
                if s.body is not None:
                    start = s.size - s.remaining
                    s.body[start:start + take] = view[pos:pos + take]
                pos += take
                s.remaining -= take
                if s.remaining:
                    continue
            self._complete(s, now, batch)

    def _count_whole(self, s: _Stream, n: int) -> int:
        """Count the whole timing-only messages at the start of the scratch buffer without
        a call per message; returns where the first incomplete one (or a bad prefix)
        starts, for :meth:`_split` to go on from."""
        unpack = _LEN.unpack_from
        view = self._view
        cap = s.max_bytes
        pos = count = total = 0
        while n - pos >= 4:
            (size,) = unpack(view, pos)
            end = pos + 4 + size
            if size > cap or end > n:
                break
            pos = end
            count += 1
            total += size
        if count:
            first = s.messages == 0
            s.messages += count
            s.pending += count
            s.pending_bytes += total
            if first:
                self._on_first(s.key)
        return pos

    def _decodable(self, s: _Stream, now: float) -> MessageArrival:
        body = s.body
        assert body is not None
        s.body = None
        decoder, name = self._decoder, s.decode_as
        assert name is not None

        def decode() -> Any:
            try:
                return decoder.decode(body, name)
            except Exception:
                return None

        return MessageArrival(now, s.topic, s.publisher, s.size, decode=decode,
                              raw=lambda: bytes(body))


def kernel_time(ancillary: list[tuple[int, int, bytes]]) -> float:
    """The ``SCM_TIMESTAMPNS`` stamp of one ``recvmsg`` as wall-clock seconds, else now."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and \
                len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            return float(sec) + float(nsec) * 1e-9
    return time.time()


@dataclass(frozen=True, slots=True)
class Handshake:
    """A connected publisher: the socket after the header exchange and the reply header."""

    sock: socket.socket
    header: dict[str, str]


def connect(publisher_uri: str, topic: str, caller_id: str, timeout: float = 1.0,
            header_cap: int = MAX_HEADER_BYTES) -> Handshake:
    """Ask the publisher for ``topic`` over TCPROS as ``caller_id`` and exchange headers.

    A rospy publisher keeps one connection per caller id, so every black box must give
    its own (see :mod:`blackbox.sources.ros1.callerid`).

    Raises :class:`RosApiError`, :class:`HeaderError` or :class:`OSError` with a reason.
    """
    proto = RosApi(publisher_uri, timeout).call("requestTopic", caller_id, topic, [["TCPROS"]])
    if not (isinstance(proto, list) and len(proto) >= 3 and proto[0] == "TCPROS"
            and isinstance(proto[1], str) and isinstance(proto[2], int)):
        raise HeaderError(f"requestTopic {topic} on {publisher_uri}: no TCPROS endpoint "
                          f"offered ({str(proto)[:80]})")
    host, port = proto[1], proto[2]
    sock = socket.create_connection((host, port), timeout=timeout)
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.sendall(encode_header({"callerid": caller_id, "topic": topic, "md5sum": "*",
                                    "type": "*", "tcp_nodelay": "1"}))
        header = read_header(sock, header_cap, f"{host}:{port}")
        if "error" in header:
            raise HeaderError(f"publisher refused {topic}: {header['error']}")
        if "type" not in header:
            raise HeaderError(f"connection header from {host}:{port} has no type")
        _keepalive(sock)
    except BaseException:
        sock.close()
        raise
    return Handshake(sock, header)


def _keepalive(sock: socket.socket) -> None:
    """Let the kernel notice a peer that vanished without closing (cable pulled, host died)."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in (("TCP_KEEPIDLE", 2), ("TCP_KEEPINTVL", 1), ("TCP_KEEPCNT", 3)):
        opt = getattr(socket, name, None)
        if opt is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, opt, value)


@dataclass(slots=True)
class _Backoff:
    delay: float
    next_try: float
    reason: str = ""


class TcprosSubscriber:
    """Keeps one connection per (topic, publisher) the observers want, with backoff.

    ``sync`` is called after every graph round with the publishers the master lists and
    the slave URIs known; it starts missing connections in a small thread pool. A
    connection is never closed just because the master stops listing it: peers talk
    directly, so data keeps flowing through a master restart.
    """

    def __init__(self, topics: frozenset[str], decoded: frozenset[str],
                 max_message_bytes: Mapping[str, int], on_message: Callable[[MessageArrival],
                 None], report: Report, connect_timeout: float = 1.0,
                 backoff_min: float = 0.1, backoff_max: float = 2.0,
                 default_max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
                 caller_id: str | None = None,
                 on_batch: Callable[[Arrivals], None] | None = None,
                 readers: int = 0, coalesce: float = 0.0) -> None:
        """``readers`` > 0 (needs ``on_batch``): timing-only connections are read by that
        many child processes (:mod:`blackbox.sources.ros1.readers`); ``coalesce``: see
        :class:`TcprosReader`."""
        self.topics = topics | decoded
        self.caller_id = caller_id or unique_caller_id()
        self.decoded = decoded
        self._caps = dict(max_message_bytes)
        self._default_cap = default_max_bytes
        self._report = report
        self._timeout = connect_timeout
        self._backoff_min = backoff_min
        self._backoff_max = backoff_max
        self.decoder = MessageDecoder()
        self.reader = TcprosReader(on_message, self._closed, self._first, self.decoder,
                                   on_batch, compact=on_batch is not None, coalesce=coalesce)
        self.processes: ReaderProcesses | None = None
        if readers > 0:
            if on_batch is None:
                raise ValueError("reader processes hand on batches: on_batch is needed")
            from blackbox.sources.ros1.readers import ReaderProcesses
            self.processes = ReaderProcesses(readers, on_batch, self._closed, self._first,
                                             report, coalesce=coalesce)
        self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="ros1-connect")
        self._lock = threading.Lock()
        self._active: set[StreamKey] = set()
        self._connecting: set[StreamKey] = set()
        self._backoff: dict[StreamKey, _Backoff] = {}
        self._released: set[StreamKey] = set()
        self.schemas: dict[str, TopicSchema] = {}
        self._closing = False

    def start(self) -> None:
        self.reader.start()
        if self.processes is not None:
            self.processes.start()

    def close(self) -> None:
        self._closing = True
        self._pool.shutdown(wait=False, cancel_futures=True)
        self.reader.close()
        if self.processes is not None:
            self.processes.close()

    def _idle_seconds(self) -> dict[StreamKey, float]:
        idle = self.reader.idle_seconds()
        if self.processes is not None:
            idle.update(self.processes.idle_seconds())
        return idle

    def _drop(self, key: StreamKey, reason: str) -> None:
        self.reader.drop(key, reason)
        if self.processes is not None:
            self.processes.drop(key, reason)

    def connected(self) -> set[StreamKey]:
        with self._lock:
            return set(self._active)

    def cap(self, topic: str) -> int:
        return self._caps.get(topic, self._default_cap)

    def sync(self, publishers: Mapping[str, tuple[str, ...]],
             uri_of: Callable[[str], str | None]) -> None:
        now = time.monotonic()
        for topic in self.topics:
            for node in publishers.get(topic, ()):
                key = StreamKey(topic, node)
                with self._lock:
                    if key in self._active or key in self._connecting:
                        continue
                    b = self._backoff.get(key)
                    if b is not None and now < b.next_try:
                        continue
                    uri = uri_of(node)
                    if uri is None:
                        continue
                    self._connecting.add(key)
                self._pool.submit(self._connect, key, uri)

    def drop_half_open(self, dead: set[str], idle_grace: float) -> None:
        """Close connections idle for ``idle_grace`` s whose publisher no longer answers.

        A peer that vanished without closing (host down, network cut) leaves a connection
        that looks healthy and never delivers; the node's own API tells it apart from a
        publisher that is merely quiet.
        """
        for key, idle in self._idle_seconds().items():
            if key.publisher in dead and idle >= idle_grace:
                self._drop(key, f"half-open: no data for {idle:.1f} s and publisher "
                                      f"{key.publisher} no longer answers its slave API")

    def _connect(self, key: StreamKey, uri: str) -> None:
        try:
            hs = connect(uri, key.topic, self.caller_id, self._timeout)
        except (RosApiError, HeaderError, OSError, struct.error) as exc:
            self._failed(key, f"cannot subscribe to {key.topic} from {key.publisher}: "
                              f"{exc or type(exc).__name__}")
            return
        except Exception as exc:
            self._failed(key, f"cannot subscribe to {key.topic} from {key.publisher}: {exc!r}")
            return
        if self._closing:
            hs.sock.close()
            return
        header = hs.header
        ros1_type = header.get("type", "")
        definition = header.get("message_definition", "")
        decode_as: str | None = None
        if key.topic in self.decoded:
            try:
                decode_as = self.decoder.register(ros1_type, definition)
            except Exception as exc:
                self._report("decode_unavailable", key.topic,
                             f"cannot decode {key.topic} ({ros1_type}) from {key.publisher}: "
                             f"bad message_definition: {exc}; counting arrivals only")
        if key.topic not in self.schemas and definition:
            self.schemas[key.topic] = TopicSchema(key.topic, ros1_type, "ros1", definition,
                                                  header.get("md5sum", ""))
        with self._lock:
            self._connecting.discard(key)
            self._active.add(key)
        if self.processes is not None and decode_as is None:
            self.processes.add(key, hs.sock, self.cap(key.topic), decode_as)
        else:
            self.reader.add(key, hs.sock, self.cap(key.topic), decode_as)

    def _first(self, key: StreamKey) -> None:
        with self._lock:
            previous = self._backoff.pop(key, None)
        if previous is not None and previous.reason:
            self._report("subscribed", key.topic,
                         f"receiving {key.topic} from {key.publisher} again")

    def release(self, key: StreamKey, reason: str) -> None:
        """Close ``key``'s connection on purpose (its rate now comes from elsewhere): no
        fault is reported and no reconnection is scheduled; ``sync`` may open it again."""
        with self._lock:
            if key not in self._active:
                return
            self._released.add(key)
        self._drop(key, reason)

    def _closed(self, key: StreamKey, reason: str, messages: int) -> None:
        with self._lock:
            self._active.discard(key)
            if key in self._released:
                self._released.discard(key)
                return
            if messages:
                self._backoff.pop(key, None)
        self._failed(key, f"lost {key.topic} from {key.publisher}: {reason}")

    def _failed(self, key: StreamKey, reason: str) -> None:
        with self._lock:
            self._connecting.discard(key)
            b = self._backoff.get(key)
            if b is None:
                b = self._backoff[key] = _Backoff(self._backoff_min, 0.0)
            else:
                b.delay = min(b.delay * 2, self._backoff_max)
            b.next_try = time.monotonic() + b.delay
            repeated = b.reason == reason
            b.reason = reason
        if not repeated:
            self._report("connection_fault", key.topic, reason)
