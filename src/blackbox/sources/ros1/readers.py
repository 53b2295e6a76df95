"""Timing-only TCPROS connections read in child processes, for rates one core cannot take.

One Python thread reads every connection of a
:class:`~blackbox.sources.ros1.stream_reader.TcprosReader` and shares the interpreter lock
with the pipeline. With ``readers=N`` (a source option) the black box starts N reader
processes; after the handshake (done in the black box, as ever) each timing-only connection
is handed to the process reading the fewest, as a file descriptor over a Unix socket
(``SCM_RIGHTS``). A child runs its own ``TcprosReader`` in compact mode and sends back, at
most every ``hand_over`` seconds, one packet of fixed-size records, one per receive: stream
id, message count, bytes and the kernel's receive time. The parent turns each record into an
:class:`~blackbox.events.ArrivalBatch`, so the pipeline sees exactly what an in-process
reader would have produced. Topics whose values are observed stay in the parent's reader
(their bytes are decoded there).

A child that dies (killed, crashed) is reported (``ros1_reader_died``) and started again;
its connections are reported closed and reconnected with the usual back-off, so nothing
else notices. Garbage on a connection closes that connection in the child, with its reason,
exactly as in the parent. A child exits when the black box goes away (its control socket
closes).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from blackbox.events import ArrivalBatch
from blackbox.sources.ros1.decoder import MessageDecoder
from blackbox.sources.ros1.stream_reader import Arrivals, StreamKey, TcprosReader

log = logging.getLogger("blackbox.sources.ros1")

_RECORD = struct.Struct("<IIQd")  # stream id, messages, bytes, kernel time
_ADD = struct.Struct("<IQ")  # stream id, max message bytes
_ID = struct.Struct("<I")
_CLOSED = struct.Struct("<IQ")  # stream id, messages on the connection
_PACKET = 1 << 16
_MAX_RECORDS = (_PACKET - 1) // _RECORD.size
DEFAULT_HAND_OVER = 0.002
_CHILD = "import sys; from blackbox.sources.ros1.readers import main; sys.exit(main(sys.argv[1:]))"
RESTART_DELAY = 0.5


@dataclass(slots=True)
class _Child:
    index: int
    proc: subprocess.Popen[bytes]
    ctrl: socket.socket
    streams: set[int] = field(default_factory=set)
    send_lock: threading.Lock = field(default_factory=threading.Lock)


@dataclass(slots=True)
class _Entry:
    key: StreamKey
    child: int
    last_rx: float
    messages: int = 0


class ReaderProcesses:
    """N child processes reading timing-only connections (see the module).

    The same calls as a ``TcprosReader`` (``start``, ``add``, ``drop``, ``idle_seconds``,
    ``close``) and the same callbacks, so the subscriber treats both alike.
    """

    def __init__(self, count: int, on_batch: Callable[[Arrivals], None],
                 on_closed: Callable[[StreamKey, str, int], None],
                 on_first: Callable[[StreamKey], None],
                 report: Callable[[str, str, str], None],
                 hand_over: float = DEFAULT_HAND_OVER, coalesce: float = 0.0) -> None:
        if count < 1:
            raise ValueError(f"reader processes must be >= 1, got {count}")
        self.count = count
        self._on_batch = on_batch
        self._on_closed = on_closed
        self._on_first = on_first
        self._report = report
        self._hand_over = hand_over
        self._coalesce = coalesce
        self._lock = threading.Lock()
        self._children: list[_Child | None] = [None] * count
        self._entries: dict[int, _Entry] = {}
        self._ids: dict[StreamKey, int] = {}
        self._next_id = 1
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.restarts = 0

    # ---- life cycle ------------------------------------------------------------------------

    def start(self) -> None:
        for i in range(self.count):
            self._spawn(i)

    def pids(self) -> list[int]:
        with self._lock:
            return [c.proc.pid for c in self._children if c is not None]

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            children = [c for c in self._children if c is not None]
        for c in children:
            with contextlib.suppress(OSError):
                c.ctrl.shutdown(socket.SHUT_RDWR)
        for c in children:
            try:
                c.proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                c.proc.kill()
                c.proc.wait()
            c.ctrl.close()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)

    def _spawn(self, index: int) -> None:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            proc = subprocess.Popen(
                [sys.executable, "-c", _CHILD, str(theirs.fileno()), repr(self._hand_over),
                 repr(self._coalesce)],
                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
        finally:
            theirs.close()
        child = _Child(index, proc, ours)
        with self._lock:
            self._children[index] = child
        thread = threading.Thread(target=self._listen, args=(child,),
                                  name=f"ros1-reader-{index}", daemon=True)
        self._threads = [t for t in self._threads if t.is_alive()]
        self._threads.append(thread)
        thread.start()

    # ---- the reader's calls ----------------------------------------------------------------

    def add(self, key: StreamKey, sock: socket.socket, max_bytes: int,
            decode_as: str | None) -> None:
        """Hand ``sock`` (a handshaken timing-only connection) to the least busy child;
        the parent's copy is closed."""
        with self._lock:
            old = self._ids.pop(key, None)
            live = [c for c in self._children if c is not None]
            old_child = None
            if old is not None:
                gone = self._forget(old)
                old_child = self._children[gone.child] if gone is not None else None
            if not live:
                sock.close()
                self._on_closed(key, "no reader process running", 0)
                return
            child = min(live, key=lambda c: len(c.streams))
            sid = self._next_id
            self._next_id += 1
            self._ids[key] = sid
            self._entries[sid] = _Entry(key, child.index, time.monotonic())
            child.streams.add(sid)
        try:
            with child.send_lock:
                socket.send_fds(child.ctrl, [b"A" + _ADD.pack(sid, max_bytes)], [sock.fileno()])
        except OSError as exc:
            with self._lock:
                self._forget(sid)
            self._on_closed(key, f"cannot hand the connection to reader process "
                                 f"{child.proc.pid}: {exc}", 0)
        finally:
            sock.close()
        if old is not None and old_child is not None:
            with contextlib.suppress(OSError), old_child.send_lock:
                old_child.ctrl.send(b"D" + _ID.pack(old) + b"replaced by a new connection")

    def drop(self, key: StreamKey, reason: str) -> None:
        with self._lock:
            sid = self._ids.get(key)
        if sid is not None:
            self._send_drop(sid, reason)

    def idle_seconds(self) -> dict[StreamKey, float]:
        now = time.monotonic()
        with self._lock:
            return {e.key: now - e.last_rx for e in self._entries.values()}

    def _send_drop(self, sid: int, reason: str) -> None:
        with self._lock:
            entry = self._entries.get(sid)
            child = self._children[entry.child] if entry is not None else None
        if child is None:
            return
        with contextlib.suppress(OSError), child.send_lock:
            child.ctrl.send(b"D" + _ID.pack(sid) + reason.encode()[:4000])

    def _forget(self, sid: int) -> _Entry | None:
        entry = self._entries.pop(sid, None)
        if entry is not None:
            if self._ids.get(entry.key) == sid:
                del self._ids[entry.key]
            child = self._children[entry.child]
            if child is not None:
                child.streams.discard(sid)
        return entry

    # ---- what the children send ------------------------------------------------------------

    def _listen(self, child: _Child) -> None:
        ctrl = child.ctrl
        entries = self._entries
        while True:
            try:
                packet = ctrl.recv(_PACKET)
            except OSError:
                packet = b""
            if not packet:
                break
            try:
                kind = packet[:1]
                if kind == b"B":
                    now = time.monotonic()
                    batch: Arrivals = []
                    for sid, count, nbytes, t in _RECORD.iter_unpack(memoryview(packet)[1:]):
                        entry = entries.get(sid)
                        if entry is None:
                            continue
                        entry.last_rx = now
                        entry.messages += count
                        key = entry.key
                        batch.append(ArrivalBatch(t, key.topic, key.publisher, count, nbytes))
                    if batch:
                        self._on_batch(batch)
                elif kind == b"F":
                    (sid,) = _ID.unpack_from(packet, 1)
                    entry = entries.get(sid)
                    if entry is not None:
                        self._on_first(entry.key)
                elif kind == b"C":
                    sid, messages = _CLOSED.unpack_from(packet, 1)
                    reason = packet[1 + _CLOSED.size:].decode(errors="replace")
                    with self._lock:
                        gone = self._forget(sid)
                    if gone is not None:
                        self._on_closed(gone.key, reason, messages)
            except Exception:  # a bad packet must not stop listening
                log.exception("reader process %s", child.proc.pid)
        self._child_gone(child)

    def _child_gone(self, child: _Child) -> None:
        with self._lock:
            if self._children[child.index] is child:
                self._children[child.index] = None
            lost = [self._forget(sid) for sid in list(child.streams)]
        child.ctrl.close()
        if self._stop.is_set():
            return
        try:
            code = child.proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            child.proc.kill()
            code = child.proc.wait()
        why = f"reader process {child.proc.pid} exited with {code}"
        self._report("reader_died", "ros1 reader",
                     f"{why}; its {len(lost)} connections are reconnected and a new reader "
                     f"process is started")
        for entry in lost:
            if entry is not None:
                self._on_closed(entry.key, why, entry.messages)
        self._stop.wait(RESTART_DELAY)  # a child that dies at once must not spin
        if not self._stop.is_set():
            self.restarts += 1
            self._spawn(child.index)


# ---- the child -------------------------------------------------------------------------------


class _ChildReader:
    """A reader process: connections come in over ``ctrl``, records go back over it."""

    def __init__(self, ctrl: socket.socket, hand_over: float, coalesce: float) -> None:
        self.ctrl = ctrl
        self.send_lock = threading.Lock()
        self.gone = False
        self.reader = TcprosReader(self._unexpected, self._closed, self._first,
                                   MessageDecoder(), on_batch=self._batch, compact=True,
                                   hand_over=hand_over, coalesce=coalesce)

    def _send(self, packet: bytes) -> None:
        if self.gone:
            return
        try:
            with self.send_lock:
                self.ctrl.sendall(packet)
        except OSError:  # the black box is gone: the main thread sees EOF and exits
            self.gone = True

    def _batch(self, batch: Arrivals) -> None:
        records = [_RECORD.pack(int(b.topic), b.count, b.bytes, b.time)
                   for b in batch if type(b) is ArrivalBatch]
        for i in range(0, len(records), _MAX_RECORDS):
            self._send(b"B" + b"".join(records[i:i + _MAX_RECORDS]))

    def _first(self, key: StreamKey) -> None:
        self._send(b"F" + _ID.pack(int(key.topic)))

    def _closed(self, key: StreamKey, reason: str, messages: int) -> None:
        self._send(b"C" + _CLOSED.pack(int(key.topic), messages) + reason.encode()[:4000])

    @staticmethod
    def _unexpected(arrival: object) -> None:
        raise AssertionError("a reader process hands on batches only")

    def run(self) -> None:
        self.reader.start()
        try:
            while True:
                msg, fds, _, _ = socket.recv_fds(self.ctrl, 8192, 1)
                if not msg:
                    break  # the black box is gone
                kind = msg[:1]
                if kind == b"A" and fds:
                    sid, max_bytes = _ADD.unpack_from(msg, 1)
                    sock = socket.socket(fileno=fds[0])
                    self.reader.add(StreamKey(str(sid), ""), sock, max_bytes, None)
                elif kind == b"D":
                    (sid,) = _ID.unpack_from(msg, 1)
                    self.reader.drop(StreamKey(str(sid), ""),
                                     msg[1 + _ID.size:].decode(errors="replace"))
                else:
                    for fd in fds:
                        os.close(fd)
        except OSError:
            pass
        finally:
            self.reader.close()


def main(argv: list[str]) -> int:
    # Ctrl-C reaches the whole process group: the black box stops us by closing the socket
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    ctrl = socket.socket(fileno=int(argv[0]))
    hand_over = float(argv[1]) if len(argv) > 1 else DEFAULT_HAND_OVER
    coalesce = float(argv[2]) if len(argv) > 2 else 0.0
    _ChildReader(ctrl, hand_over, coalesce).run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
