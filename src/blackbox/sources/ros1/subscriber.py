"""TCPROS subscriber connections made by hand, one per publisher, never registered.

The black box asks a publisher directly for a connection (``requestTopic`` on its slave
API), so the master never lists it as a subscriber. After the header exchange every
connection is read by one selector thread (:mod:`blackbox.sources.ros1.stream_reader`) or,
for timing-only topics at high rates, by reader processes
(:mod:`blackbox.sources.ros1.readers`). Values are decoded from the ``message_definition``
the publisher sent in its connection header.

Whatever a publisher sends, the black box keeps going: malformed headers, absurd length
prefixes (beyond a per-topic cap) and silent dead peers close that one connection with a
reason, and the connection is retried with backoff.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from blackbox.events import MessageArrival, TopicSchema
from blackbox.sources.ros1.callerid import unique_caller_id
from blackbox.sources.ros1.decoder import MessageDecoder
from blackbox.sources.ros1.master import Report, RosApi, RosApiError
from blackbox.sources.ros1.readers import ReaderProcesses
from blackbox.sources.ros1.stream_reader import Arrivals, StreamKey, TcprosReader
from blackbox.sources.ros1.wire import MAX_HEADER_BYTES, HeaderError, encode_header, read_header

DEFAULT_MAX_MESSAGE_BYTES = 64 * 1024 * 1024


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
