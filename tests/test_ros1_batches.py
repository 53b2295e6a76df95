"""The fast receive path on a real roscore: timing-only topics arrive as compact batches,
optionally read in child processes, and count and time exactly what the per-message path
does; a reader process that dies or meets garbage costs nothing else."""

from __future__ import annotations

import os
import random
import shutil
import signal
import socket
import struct
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
import ros1_watch
from blackbox.config.node import ConfigNode
from blackbox.events import ArrivalBatch, Event, Interest, MessageArrival
from blackbox.model import BlackBoxEvent
from blackbox.observe.base import OBSERVERS
from blackbox.sources.ros1 import Ros1Settings, Ros1Source
from test_ros1_faults import FakePublisher, _float_header

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from robot import ThesisRobot, free_port

pytestmark = [pytest.mark.xdist_group("test_ros1_batches"),  # its module fixture: one worker
              pytest.mark.ros1,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

IMAGE = "/usb_cam/image_raw"
BURST = 20_000


def settings(readers: int = 0) -> Ros1Settings:
    return Ros1Settings(rates_from_counters=False, readers=readers, backoff_min=0.1,
                        backoff_max=0.4)


class Watch(ros1_watch.Watch):
    """The shared poller, with this file's views of the events."""

    def count(self, topic: str, since: float = 0.0) -> int:
        return sum(e.count if type(e) is ArrivalBatch else 1 for e in self.events
                   if type(e) in (ArrivalBatch, MessageArrival) and e.topic == topic
                   and e.time >= since)

    def of(self, kind: type, topic: str) -> list[Event]:
        return [e for e in self.events if type(e) is kind and getattr(e, "topic", "") == topic]

    def faults(self, kind: str) -> list[BlackBoxEvent]:
        return [e for e in self.events if isinstance(e, BlackBoxEvent) and kind in e.kind]


def watch(robot: ThesisRobot, topics: set[str], decoded: set[str] = frozenset(),
          batches: bool = True, readers: int = 0) -> Watch:
    source = Ros1Source(robot.master_uri + "/", settings(readers))
    source.start(Interest(topics=frozenset(topics), decoded=frozenset(decoded),
                          arrival_batches=batches))
    return Watch(source)


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ThesisRobot]:
    r = ThesisRobot(free_port(), log_dir=tmp_path_factory.mktemp("logs"))
    try:
        yield r.start()
    finally:
        r.stop()


def burst(topic: str, seed: int) -> Callable[[socket.socket], None]:
    """Serves the header, then BURST Float64 frames in writes of random sizes (prefixes
    and bodies split across them, many messages per write)."""
    frames = (struct.pack("<I", 8) + struct.pack("<d", 1.0)) * BURST
    rng = random.Random(seed)

    def serve(conn: socket.socket) -> None:
        conn.sendall(_float_header(topic))
        pos = 0
        while pos < len(frames):
            step = rng.choice([1, 3, 12, 100, 5000, 65536])
            conn.sendall(frames[pos:pos + step])
            pos += step

    return serve


@pytest.mark.parametrize("mode", ["messages", "batches", "processes"])
def test_a_burst_is_counted_exactly_one_by_one_in_batches_and_in_reader_processes(
        robot: ThesisRobot, mode: str, receive_path: str) -> None:
    topic = f"/burst_{mode}_{receive_path}"
    fake = FakePublisher(robot.master_uri, topic, burst(topic, 7),
                         f"/burster_{mode}_{receive_path}")
    w = watch(robot, {topic}, batches=mode != "messages",
              readers=1 if mode == "processes" else 0)
    try:
        assert w.until(lambda: w.count(topic) >= BURST, timeout=20.0)
        time.sleep(0.3)
        w.until(lambda: False, timeout=0.3)
        assert w.count(topic) == BURST
        batches = w.of(ArrivalBatch, topic)
        if mode == "messages":
            assert batches == []
        else:
            assert w.of(MessageArrival, topic) == []
            assert len(batches) < BURST / 10  # many messages per receive, no object each
            assert sum(b.bytes for b in batches) == 8 * BURST  # type: ignore[union-attr]
        if mode == "processes":
            assert w.source.reader_processes is not None
            assert len(w.source.reader_processes.pids()) == 1
        times = [e.time for e in w.events]
        assert times == sorted(times)  # handed out in time order
    finally:
        w.source.close()
        fake.close()


def hz_reading(events: list[Event], topic: str, start: float = float("-inf"),
               end: float = float("inf")) -> float:
    """The hz observer's reading of ``topic`` from the arrivals between ``start`` and
    ``end`` (two paths compared over the same window: the robot's rate wanders on a
    loaded machine, so their last messages must be the same ones)."""
    hz = OBSERVERS["hz"].build(ConfigNode.parse(
        f"type: hz\ntopic: {topic}\nfilter: {{type: mean, window_size: 30}}\n", "t.yaml"))
    for e in events:
        if not start <= getattr(e, "time", start) <= end:
            continue
        if type(e) is ArrivalBatch and e.topic == topic:
            hz.on_batch(e)  # type: ignore[attr-defined]
        elif type(e) is MessageArrival and e.topic == topic:
            hz.on_message(e)
    summary = hz.period.summary()  # type: ignore[attr-defined]
    return 1.0 / summary.value


def test_batches_in_a_reader_process_count_and_time_like_the_per_message_path(
        robot: ThesisRobot) -> None:
    """Two black boxes on the same real rospy topics over the same seconds: one takes each
    message as an arrival, the other batches read in a child process."""
    topics = {IMAGE, "/signal"}
    one_by_one = watch(robot, topics, batches=False)
    batched = watch(robot, topics, batches=True, readers=1)
    try:
        def both() -> bool:
            batched.until(lambda: True)
            return all(one_by_one.count(t) >= 5 and batched.count(t) >= 5 for t in topics)

        assert one_by_one.until(both)
        start = time.time() + 0.5
        deadline = start + 3.0
        while time.time() < deadline:
            one_by_one.until(lambda: True)
            batched.until(lambda: True)
        end = deadline - 0.5
        for topic in topics:
            a = [e for e in one_by_one.events if getattr(e, "topic", "") == topic
                 and start <= e.time <= end]
            b = [e for e in batched.events if getattr(e, "topic", "") == topic
                 and start <= e.time <= end]
            assert all(type(e) is MessageArrival for e in a)
            assert all(type(e) is ArrivalBatch for e in b)
            n_a, n_b = len(a), sum(e.count for e in b)  # type: ignore[union-attr]
            assert n_a > 20
            assert abs(n_a - n_b) <= 1  # only a message on the window's edge may differ
            assert hz_reading(one_by_one.events, topic, start, end) == \
                pytest.approx(hz_reading(batched.events, topic, start, end), rel=0.01)
    finally:
        one_by_one.source.close()
        batched.source.close()


def test_a_killed_reader_process_is_reported_restarted_and_its_topics_come_back(
        robot: ThesisRobot) -> None:
    w = watch(robot, {IMAGE}, decoded={"/signal"}, readers=1)
    try:
        assert w.until(lambda: w.count(IMAGE) >= 5 and w.count("/signal") >= 5)
        processes = w.source.reader_processes
        assert processes is not None
        (old,) = processes.pids()
        killed = time.time()
        os.kill(old, signal.SIGKILL)
        assert w.until(lambda: w.faults("reader_died") != [])
        died = w.faults("reader_died")[0]
        assert f"reader process {old} exited with -9" in died.message
        assert w.until(lambda: w.count(IMAGE, since=killed + 0.1) >= 5)
        (new,) = processes.pids()
        assert new != old and processes.restarts == 1
        # decoded topics are read by the black box itself: they never stopped
        assert w.until(lambda: w.count("/signal", since=killed + 1.0) >= 1)
        assert w.count("/signal", since=killed) >= 5
        assert [m.value.data for m in w.of(MessageArrival, "/signal")][-1] is not None  # type: ignore[union-attr]
    finally:
        w.source.close()
    assert not os.path.exists(f"/proc/{new}") or _zombie_or_gone(new)


def _zombie_or_gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] in ("Z", "X")
    except OSError:
        return True


@pytest.mark.parametrize("garbage", ["length", "random"])
def test_garbage_in_a_reader_process_closes_only_that_connection(
        robot: ThesisRobot, garbage: str, receive_path: str) -> None:
    junk = f"/junk_{garbage}_{receive_path}"
    rng = random.Random(3)
    body = (struct.pack("<I", 0xFFFFFFF0) if garbage == "length"
            else struct.pack("<I", 8) + b"\x00" * 8 + bytes(rng.randrange(256)
                                                            for _ in range(4096)))
    fake = FakePublisher(robot.master_uri, junk, lambda c: c.sendall(_float_header(junk) + body),
                         f"/garbage_{garbage}_{receive_path}")
    w = watch(robot, {junk, IMAGE}, readers=1)
    try:
        assert w.until(lambda: fake.connections >= 2 and w.count(IMAGE) >= 10)
        reasons = [f.message for f in w.faults("connection_fault") if f.component == junk]
        assert reasons and "exceeds the cap of 67108864 bytes" in reasons[0]
        processes = w.source.reader_processes
        assert processes is not None and processes.restarts == 0
        assert w.faults("reader_died") == []
        seen = time.time()
        assert w.until(lambda: w.count(IMAGE, since=seen) >= 5)
    finally:
        w.source.close()
        fake.close()
