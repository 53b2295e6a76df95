"""One thread reading every TCPROS connection through a selector.

Topics observed for timing only are read into a shared scratch buffer and never decoded:
per message the cost is a length prefix and a few counters. Topics whose values are
observed keep their bytes and decode lazily
(:class:`~blackbox.sources.ros1.decoder.MessageDecoder`).

Each wake-up reads everything the socket holds (up to 256 KiB) in one ``recvmsg`` and splits
every message out of that one buffer; the arrivals of one read are handed on together, so
the hand-over lock is taken once per read, not once per message. Arrival times come from the
kernel (``SO_TIMESTAMPNS``: when the last segment of the read reached the socket), not from
when Python got round to reading, so a reader that is late by some milliseconds does not
distort inter-arrival times; where the kernel gives no stamp, the wall clock at the read is
used.

An absurd length prefix (beyond a per-topic cap) or a dead peer closes that one connection
with a reason; the subscriber decides what happens next.

Where the native loop is built (:mod:`blackbox.sources.ros1.native`, ``_tcpros.c``), the
waiting, reading and splitting above run in C with the interpreter lock released, and Python
wakes once per hand-over with the same arrivals, times and reasons; in compact mode the C
loop builds the :class:`ArrivalBatch` events itself, so no Python code runs per receive;
the Python code here stays as the fallback and the reference that both are tested against.
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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

from blackbox.events import ArrivalBatch, MessageArrival
from blackbox.sources.ros1.decoder import MessageDecoder
from blackbox.sources.ros1.native import native_loop
from blackbox.sources.ros1.wire import LENGTH

log = logging.getLogger("blackbox.sources.ros1")

_SCRATCH_BYTES = 256 * 1024
_SKIP_BYTES = 4 * 1024 * 1024
_LOWAT_CAP = _SKIP_BYTES
_READS_PER_WAKEUP = 16
NATIVE_HAND_OVER = 0.25
"""Seconds the native loop collects at most before it wakes the interpreter on its own;
whoever takes the arrivals asks for them when it needs them (:meth:`TcprosReader.flush`,
the source at every poll), so they are never late for the pipeline, and a camera's frames
cost no interpreter wake-up each. Kernel times are unchanged."""
FLUSH_TIMEOUT = 0.1
"""At most this long :meth:`TcprosReader.flush` waits for the reader thread."""
# Linux: SO_TIMESTAMPNS (== SCM_TIMESTAMPNS) delivers a struct timespec per recvmsg.
SO_TIMESTAMPNS: int | None = getattr(socket, "SO_TIMESTAMPNS", 35 if hasattr(socket, "AF_NETLINK")
                                     else None)
_TIMESPEC = struct.Struct("@qq")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0


@dataclass(frozen=True, slots=True)
class StreamKey:
    topic: str
    publisher: str


class _Stream:
    """Reading state of one established connection."""

    __slots__ = ("body", "closed", "decode_as", "key", "last_rx", "lenbuf", "lenfill",
                 "lowat", "max_bytes", "messages", "pending", "pending_bytes", "publisher",
                 "remaining", "sid", "size", "sock", "topic")

    def __init__(self, key: StreamKey, sock: socket.socket, max_bytes: int,
                 decode_as: str | None, sid: int = 0) -> None:
        self.key = key
        self.sid = sid  # the native loop's name for the connection
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
                 compact: bool = False, hand_over: float | None = None,
                 coalesce: float = 0.0) -> None:
        """``on_batch`` receives the arrivals of one wake-up together (preferred, one
        call per wake-up); without it ``on_message`` is called per message.

        ``compact``: the messages of a timing-only connection that one receive got are
        handed on as one :class:`ArrivalBatch` (no object per message); otherwise as
        one :class:`MessageArrival` each (``on_message`` always gets arrivals).

        ``hand_over``: hand on at most every this many seconds what the wake-ups since
        read (fewer wake-ups of whoever takes them; arrival times are unchanged). By
        default :data:`NATIVE_HAND_OVER` with the native loop (the consumer calls
        :meth:`flush` when it wants what has arrived), 0 in Python.

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
        self._native = native_loop()
        if hand_over is None:
            hand_over = NATIVE_HAND_OVER if self._native is not None else 0.0
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
        self._engine: Any = None
        self._sids: dict[int, _Stream] = {}
        self._next_sid = 1
        if self._native is not None:
            # compact: the loop builds the ArrivalBatch objects itself (no Python per receive)
            self._engine = self._native.Engine(self._wake_r.fileno(), compact,
                                               ArrivalBatch if compact else None)
        else:
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
        self._flushed = threading.Condition()
        self._flush_asked = self._flush_done = 0
        self._stop = threading.Event()
        run = self._run if self._engine is None else self._run_native
        self._thread = threading.Thread(target=run, name="ros1-tcpros", daemon=True)

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

    def flush(self, timeout: float = FLUSH_TIMEOUT) -> bool:
        """Hand on now everything received so far (the native loop holds arrivals up to
        ``hand_over``); returns once the reader thread has (``True``), or after ``timeout``
        (``False``: the reader thread did not run meanwhile). A no-op for the Python
        reader, which hands on at once."""
        if self._engine is None or self._hand_over_every <= 0 or not self._thread.is_alive():
            return True
        with self._flushed:
            self._flush_asked += 1
            want = self._flush_asked
        self._wake()
        with self._flushed:
            return self._flushed.wait_for(
                lambda: self._flush_done >= want or self._stop.is_set(), timeout)

    def drop(self, key: StreamKey, reason: str) -> None:
        """Close ``key``'s connection from another thread (half-open, lost interest)."""
        with self._lock:
            self._drop.append((key, reason))
        self._wake()

    @property
    def native(self) -> bool:
        """Whether this reader runs the compiled loop."""
        return self._engine is not None

    def idle_seconds(self) -> dict[StreamKey, float]:
        if self._engine is not None:
            idle = self._engine.idle()
            return {s.key: idle[sid] for sid, s in list(self._sids.items()) if sid in idle}
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
        self._sids.clear()
        self._engine = None  # its epoll descriptor goes with it
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

    def _run_native(self) -> None:
        """The loop of the compiled reader: one ``poll`` waits, reads and splits until a
        hand-over is due; here its records become arrivals."""
        native, engine = self._native, self._engine
        assert native is not None and engine is not None
        arrivals, body, first, closed = native.ARRIVALS, native.BODY, native.FIRST, \
            native.CLOSED
        sids = self._sids
        held = self._held
        compact = self._compact
        stop = self._stop
        while not stop.is_set():
            try:
                records, woken, objects = engine.poll(1.0, self._hand_over_every,
                                                      self._coalesce)
            except OSError:
                log.exception("TCPROS reader")
                stop.wait(0.1)  # an epoll that fails must not spin
                continue
            ended: list[tuple[_Stream, str]] = []
            if objects == len(records):  # timing-only arrivals, already ArrivalBatch objects
                held.extend(records)
                records = ()
            for record in records:
                if type(record) is ArrivalBatch:  # made by the loop; counted there
                    held.append(record)
                    continue
                kind = record[0]
                s = sids.get(record[1])
                if s is None:
                    continue
                if kind == arrivals:
                    _, _, count, nbytes, t = record
                    s.messages += count
                    held.append(ArrivalBatch(t, s.topic, s.publisher, count, nbytes)
                                if compact else MessageArrival(t, s.topic, s.publisher, nbytes))
                elif kind == body:
                    _, _, size, data, t = record
                    s.messages += 1
                    held.append(decodable_arrival(self._decoder, s, size, data, t))
                elif kind == first:
                    self._on_first(s.key)
                elif kind == closed:  # closed once the receive's messages are counted
                    reason = record[3]
                    if reason.startswith("message length prefix"):
                        reason += f" for {s.topic} (garbage or oversized message)"
                    ended.append((s, reason))
            for s, reason in ended:
                self._close(s, reason)
            if woken:
                try:
                    self._service_wakeup()
                except Exception:  # one bad connection must not stop the reader
                    log.exception("TCPROS reader")
            if held:
                self._hand_over()
                held = self._held
            while self._closed_notes:
                self._on_closed(*self._closed_notes.pop(0))
            if woken and self._flush_done < self._flush_asked:
                with self._flushed:  # what was asked for before this poll returned is out
                    self._flush_done = self._flush_asked
                    self._flushed.notify_all()
        if self._held:
            self._hand_over()
        with self._flushed:
            self._flushed.notify_all()

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
            if self._engine is None:
                self._selector.register(stream.sock, selectors.EVENT_READ, stream)
                continue
            stream.sid, self._next_sid = self._next_sid, self._next_sid + 1
            self._sids[stream.sid] = stream
            names = (stream.topic, stream.publisher) if stream.decode_as is None else ()
            try:
                self._engine.add(stream.sid, stream.sock.fileno(), stream.max_bytes,
                                 stream.decode_as is not None, *names)
            except (OSError, ValueError) as exc:
                self._close(stream, f"cannot read the connection: {exc}")
        for key, reason in drops:
            dropped = self._streams.get(key)
            if dropped is not None:
                self._close(dropped, reason)

    def _close(self, stream: _Stream, reason: str, notify: bool = True) -> None:
        stream.closed = True
        if self._engine is not None and self._sids.pop(stream.sid, None) is not None:
            messages = self._engine.remove(stream.sid)
            if messages >= 0:
                stream.messages = messages
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
            body, s.body = s.body, None
            batch.append(decodable_arrival(self._decoder, s, s.size, body, now))
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
                    (size,) = LENGTH.unpack_from(view, pos)
                    pos += 4
                else:
                    take = min(4 - s.lenfill, n - pos)
                    s.lenbuf[s.lenfill:s.lenfill + take] = view[pos:pos + take]
                    s.lenfill += take
                    pos += take
                    if s.lenfill < 4:
                        break
                    (size,) = LENGTH.unpack_from(s.lenbuf, 0)
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
        unpack = LENGTH.unpack_from
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



def decodable_arrival(decoder: MessageDecoder, s: _Stream, size: int,
                      body: bytes | bytearray, now: float) -> MessageArrival:
    """The arrival of a message whose value is observed: decoded when first asked for."""
    name = s.decode_as
    assert name is not None

    def decode() -> Any:
        try:
            return decoder.decode(body, name)
        except Exception:
            return None

    return MessageArrival(now, s.topic, s.publisher, size, decode=decode,
                          raw=lambda: bytes(body))


def kernel_time(ancillary: list[tuple[int, int, bytes]]) -> float:
    """The ``SCM_TIMESTAMPNS`` stamp of one ``recvmsg`` as wall-clock seconds, else now."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and \
                len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            return float(sec) + float(nsec) * 1e-9
    return time.time()
