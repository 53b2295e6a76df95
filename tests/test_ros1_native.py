"""The native TCPROS receive loop: built by the project's setup where a C compiler is, the
Python fallback announced in one line where it is not, and bad input on either path handled
the same way (a reason for the one connection, no crash, the other connections read on)."""

from __future__ import annotations

import gc
import os
import random
import shutil
import socket
import struct
import subprocess
import sys
import sysconfig
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from blackbox.events import ArrivalBatch, MessageArrival
from blackbox.sources.ros1.decoder import MessageDecoder
from blackbox.sources.ros1.native import FORCE_PYTHON
from blackbox.sources.ros1.stream_reader import Arrivals, StreamKey, TcprosReader
from conftest import wait_until

GOOD = StreamKey("/good", "/talker")
BAD = StreamKey("/bad", "/evil")


class _Seen:
    """What a compact reader handed on, per connection."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.sizes: dict[StreamKey, list[int]] = {}
        self.closed: dict[StreamKey, tuple[str, int]] = {}
        self.first: list[StreamKey] = []
        self.items: list[object] = []

    def on_batch(self, batch: Arrivals) -> None:
        with self.lock:
            self.items.extend(batch)
            for item in batch:
                key = StreamKey(item.topic, item.publisher)
                if type(item) is ArrivalBatch:
                    self.sizes.setdefault(key, []).extend(a.size for a in item.arrivals())
                else:
                    self.sizes.setdefault(key, []).append(item.size)

    def on_closed(self, key: StreamKey, reason: str, messages: int) -> None:
        with self.lock:
            self.closed[key] = (reason, messages)

    def count(self, key: StreamKey) -> int:
        with self.lock:
            return len(self.sizes.get(key, []))


def _unexpected(arrival: MessageArrival) -> None:
    raise AssertionError("a reader with on_batch hands on batches")


@contextmanager
def _reader(compact: bool = False) -> Iterator[tuple[TcprosReader, _Seen]]:
    seen = _Seen()
    reader = TcprosReader(_unexpected, seen.on_closed, seen.first.append, MessageDecoder(),
                          on_batch=seen.on_batch, compact=compact)
    reader.start()
    try:
        yield reader, seen
    finally:
        reader.close()


def _frame(body: bytes) -> bytes:
    return struct.pack("<I", len(body)) + body


def _tcp_pair() -> tuple[socket.socket, socket.socket]:
    with socket.create_server(("127.0.0.1", 0)) as server:
        theirs = socket.create_connection(server.getsockname())
        ours, _ = server.accept()
    return ours, theirs


def _good_keeps_flowing(reader: TcprosReader, seen: _Seen, talker: socket.socket,
                        n: int) -> None:
    """The healthy connection beside the bad one is still read, message by message."""
    before = seen.count(GOOD)
    for i in range(n):
        talker.sendall(_frame(bytes(i % 5)))
    wait_until(lambda: seen.count(GOOD) == before + n,
               f"{n} more messages on the healthy connection")


def test_the_native_loop_is_built_where_a_c_compiler_is() -> None:
    """scripts/setup.sh compiles _tcpros.c; a machine with gcc must not silently run the
    slow path."""
    compiler = (sysconfig.get_config_var("CC") or "cc").split()[0]
    if not sys.platform.startswith("linux") or shutil.which(compiler) is None:
        pytest.skip(f"no C compiler ({compiler}) or not Linux: the fallback is expected")
    env = {k: v for k, v in os.environ.items() if k != FORCE_PYTHON}
    out = subprocess.run(
        [sys.executable, "-c", "from blackbox.sources.ros1.native import native_loop; "
         "print(native_loop() is not None)"], env=env, capture_output=True, text=True,
        timeout=60, check=True)
    assert out.stdout.strip() == "True", out.stderr
    assert out.stderr == ""


def test_the_fallback_says_so_in_one_line_however_many_readers_start() -> None:
    script = ("from blackbox.sources.ros1.stream_reader import TcprosReader\n"
              "from blackbox.sources.ros1.decoder import MessageDecoder\n"
              "for _ in range(3):\n"
              "    r = TcprosReader(print, print, print, MessageDecoder())\n"
              "    assert not r.native\n"
              "    r.start(); r.close()\n")
    out = subprocess.run([sys.executable, "-c", script], env={**os.environ, FORCE_PYTHON: "1"},
                         capture_output=True, text=True, timeout=60, check=True)
    assert out.stderr.splitlines() == [
        f"ros1: reading TCPROS in Python (slower per message): {FORCE_PYTHON}=1"]


@pytest.mark.parametrize("compact", [False, True], ids=["messages", "batches"])
def test_a_frame_cut_off_by_the_peer_is_not_counted(receive_path: str, compact: bool) -> None:
    with _reader(compact) as (reader, seen):
        ours, theirs = socket.socketpair()
        reader.add(BAD, ours, 1 << 20, None)
        theirs.sendall(_frame(b"whole") + struct.pack("<I", 100) + b"only ten b")
        theirs.close()
        wait_until(lambda: BAD in seen.closed, "the cut-off connection to be reported closed")
    assert seen.closed[BAD] == ("publisher closed the connection", 1)
    assert seen.sizes[BAD] == [5]


@pytest.mark.parametrize("prefix", [0xFFFFFFFF, 0x100000000 - 4, (1 << 20) + 1])
def test_a_4_gb_length_prefix_closes_that_connection_only(receive_path: str,
                                                           prefix: int) -> None:
    with _reader(compact=True) as (reader, seen):
        ours, theirs = _tcp_pair()
        good, talker = _tcp_pair()
        reader.add(BAD, ours, 1 << 20, None)
        reader.add(GOOD, good, 1 << 20, None)
        theirs.sendall(_frame(b"ok") + struct.pack("<I", prefix) + b"\xff" * 64)
        wait_until(lambda: BAD in seen.closed, "the 4 GB prefix to close its connection")
        _good_keeps_flowing(reader, seen, talker, 50)
        for s in (theirs, talker):
            s.close()
    assert seen.closed[BAD] == (f"message length prefix of {prefix} bytes exceeds the cap of "
                                f"{1 << 20} bytes for /bad (garbage or oversized message)", 1)
    assert seen.sizes[BAD] == [2]
    assert seen.first == [BAD, GOOD] or seen.first == [GOOD, BAD]


def _garbage_outcome(seed: int) -> tuple[list[int], tuple[str, int], int]:
    """What a reader makes of random bytes in random writes, then a reset connection."""
    rng = random.Random(seed)
    junk = b"".join(_frame(bytes(rng.randrange(256) for _ in range(rng.randrange(40))))
                    for _ in range(30))
    junk += bytes(rng.randrange(256) for _ in range(5000))
    with _reader() as (reader, seen):
        ours, theirs = _tcp_pair()
        good, talker = _tcp_pair()
        reader.add(BAD, ours, 4096, None)
        reader.add(GOOD, good, 4096, None)
        pos = 0
        while pos < len(junk):
            step = rng.choice([1, 3, 7, 100, 1000])
            try:
                theirs.sendall(junk[pos:pos + step])
            except OSError:
                break  # the reader closed the connection on a bad prefix
            pos += step
        if BAD not in seen.closed:  # reset, not a clean close
            theirs.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        theirs.close()
        wait_until(lambda: BAD in seen.closed, "the garbage connection to be closed")
        _good_keeps_flowing(reader, seen, talker, 20)
        talker.close()
        return seen.sizes.get(BAD, []), seen.closed[BAD], seen.count(GOOD)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_garbage_gives_the_same_arrivals_and_reason_on_both_paths(
        monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    from blackbox.sources.ros1.native import native_loop

    if native_loop() is None:
        pytest.skip("the native TCPROS loop is not built here")
    native = _garbage_outcome(seed)
    monkeypatch.setenv(FORCE_PYTHON, "1")
    python = _garbage_outcome(seed)
    assert native == python
    sizes, (reason, messages), good = native
    assert messages == len(sizes) and len(sizes) >= 30 and good == 20
    assert "exceeds the cap of 4096 bytes" in reason or reason in (
        "connection error: [Errno 104] Connection reset by peer",
        "publisher closed the connection")


def test_a_peer_that_stalls_mid_frame_is_idle_not_stuck(receive_path: str) -> None:
    """Half a message, then silence: the other connection is read on, the stalled one's
    idle time grows (the subscriber closes half-open connections on it) and it can be
    dropped with a reason; the half message is never counted."""
    with _reader(compact=True) as (reader, seen):
        ours, theirs = _tcp_pair()
        good, talker = _tcp_pair()
        reader.add(BAD, ours, 1 << 20, None)
        reader.add(GOOD, good, 1 << 20, None)
        theirs.sendall(_frame(b"x" * 10) + struct.pack("<I", 500_000) + b"y" * 1000)
        wait_until(lambda: seen.count(BAD) == 1, "the stalled peer's whole message")
        _good_keeps_flowing(reader, seen, talker, 30)
        wait_until(lambda: reader.idle_seconds().get(BAD, 0.0) >= 0.3,
                   "the stalled connection to be idle for 0.3 s")
        assert reader.idle_seconds()[GOOD] < reader.idle_seconds()[BAD]
        reader.drop(BAD, "half-open: the publisher's node does not answer")
        wait_until(lambda: BAD in seen.closed, "the dropped connection to be reported")
        _good_keeps_flowing(reader, seen, talker, 10)
        assert BAD not in reader.idle_seconds()
        for s in (theirs, talker):
            s.close()
    assert seen.closed[BAD] == ("half-open: the publisher's node does not answer", 1)
    assert seen.sizes[BAD] == [10]


def test_the_native_loop_wakes_the_interpreter_when_asked_not_per_message() -> None:
    """Spaced messages (a camera's frames) are held in C until ``flush`` (the source calls
    it at every poll) or the hand-over backstop; after ``flush`` everything the socket had
    received is handed on, with each receive's own kernel time."""
    from blackbox.sources.ros1.native import native_loop

    if native_loop() is None:
        pytest.skip("the native TCPROS loop is not built here")
    handed: list[Arrivals] = []
    reader = TcprosReader(_unexpected, lambda *a: None, lambda key: None, MessageDecoder(),
                          on_batch=handed.append, compact=True)
    reader.start()
    ours, theirs = socket.socketpair()
    try:
        assert reader.native
        reader.add(GOOD, ours, 1 << 20, None)
        theirs.sendall(_frame(b"first"))
        wait_until(lambda: reader.idle_seconds().get(GOOD, 1.0) < 0.5, "the first receive")
        reader.flush()
        first_wakeups = len(handed)
        for i in range(20):
            theirs.sendall(_frame(bytes(i)))
            time.sleep(0.005)  # one receive each

        def counted() -> int:
            reader.flush()  # hands on only when something is held
            return sum(x.count for h in handed for x in h)

        wait_until(lambda: counted() == 21, "all 21 messages after a flush")
        items = [x for h in handed for x in h]
        # flushes every 50 ms while waiting, not one wake-up per message
        assert len(handed) - first_wakeups < 10
        times = [x.time for x in items]
        assert times == sorted(times) and len(set(times)) >= 15  # receive times kept
    finally:
        reader.close()
        theirs.close()


def test_flush_is_a_no_op_for_the_python_reader(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(FORCE_PYTHON, "1")
    with _reader() as (reader, _):
        assert not reader.native
        started = time.monotonic()
        reader.flush(timeout=5.0)
        assert time.monotonic() - started < 1.0


def test_timing_only_arrivals_are_arrival_batches_with_the_connection_names(
        receive_path: str) -> None:
    """The native loop builds the ArrivalBatch objects itself (no Python per receive); what
    it builds is what the Python reader builds: the event class, the connection's topic and
    publisher, the messages' count and bytes, a kernel time on the wall clock."""
    sizes = [3, 0, 17, 250, 8]
    with _reader(compact=True) as (reader, seen):
        ours, theirs = _tcp_pair()
        reader.add(GOOD, ours, 1 << 20, None)
        sent = time.time()
        for n, size in enumerate(sizes, start=1):
            theirs.sendall(_frame(b"s" * size))
            wait_until(lambda n=n: (reader.flush(), seen.count(GOOD))[1] >= n,
                       f"message {n} to be handed on")
        theirs.close()
        handed = list(seen.items)
    assert all(type(item) is ArrivalBatch for item in handed)
    batches = [item for item in handed if isinstance(item, ArrivalBatch)]
    assert {(b.topic, b.publisher) for b in batches} == {(GOOD.topic, GOOD.publisher)}
    assert sum(b.count for b in batches) == len(sizes)
    assert sum(b.bytes for b in batches) == sum(sizes)
    assert all(type(b.time) is float and type(b.count) is int and type(b.bytes) is int
               for b in batches)
    times = [b.time for b in batches]
    assert times == sorted(times) and sent - 1.0 < times[0] <= times[-1] < time.time() + 1.0


def test_the_native_loop_refuses_an_event_class_it_cannot_fill() -> None:
    """The loop fills ArrivalBatch's slots directly; a class without those plain slots is
    refused when the loop is made, never written to."""
    from blackbox.sources.ros1.native import native_loop

    native = native_loop()
    if native is None:
        pytest.skip("the native TCPROS loop is not built here")

    class NoSlots:
        def __init__(self) -> None:
            self.time = self.topic = self.publisher = self.count = self.bytes = None

    class WrongSlots:
        __slots__ = ("time", "topic")

    r, w = socket.socketpair()
    with r, w:
        for bad in (NoSlots, WrongSlots, 42):
            with pytest.raises((TypeError, AttributeError)):
                native.Engine(r.fileno(), True, bad)
        native.Engine(r.fileno(), True, ArrivalBatch)  # the real one is accepted


def test_the_native_loop_keeps_no_reference_to_what_it_handed_on() -> None:
    """Batches made in C own their references like any other object: once the consumer and
    the reader are gone, the topic and publisher names are back to their reference count."""
    from blackbox.sources.ros1.native import native_loop

    if native_loop() is None:
        pytest.skip("the native TCPROS loop is not built here")
    key = StreamKey("".join(["/refcount", "/topic"]), "".join(["/refcount", "/node"]))
    baseline = sys.getrefcount(key.topic), sys.getrefcount(key.publisher)
    handed: list[Arrivals] = []
    reader = TcprosReader(_unexpected, lambda *a: None, lambda k: None, MessageDecoder(),
                          on_batch=handed.append, compact=True)
    reader.start()
    ours, theirs = socket.socketpair()
    try:
        reader.add(key, ours, 1 << 20, None)
        for i in range(50):
            theirs.sendall(_frame(bytes(i % 7)))
            if i % 10 == 0:
                time.sleep(0.002)
        wait_until(lambda: (reader.flush(), sum(x.count for h in handed for x in h))[1] == 50,
                   "all 50 messages handed on")
    finally:
        reader.close()
        theirs.close()
    assert all(type(x) is ArrivalBatch for h in handed for x in h)
    handed.clear()  # the reader closed: its loop and the streams in it are gone
    gc.collect()
    assert (sys.getrefcount(key.topic), sys.getrefcount(key.publisher)) == baseline
