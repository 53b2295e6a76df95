"""Robot-side faults never stop Ros1Source: real processes killed, stopped and restarted,
a restarted master, and fake publishers that send garbage or go silent."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import struct
import sys
import threading
import time
import xmlrpc.client
from collections.abc import Callable, Iterator
from pathlib import Path
from xmlrpc.server import SimpleXMLRPCServer

import pytest

import ros1_watch
from blackbox.events import GraphSnapshot, Interest, MessageArrival
from blackbox.model import BlackBoxEvent
from blackbox.sources.ros1 import Ros1Settings, Ros1Source
from blackbox.sources.ros1.wire import encode_header

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from robot import ThesisRobot, free_port

pytestmark = [pytest.mark.xdist_group("test_ros1_faults"),  # its module fixture: one worker
              pytest.mark.ros1,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

IMAGE = "/usb_cam/image_raw"


class Watch(ros1_watch.Watch):
    """The shared poller, with this file's views of the events."""

    def graphs(self, since: float = 0.0) -> list[GraphSnapshot]:
        return [e for e in self.events if isinstance(e, GraphSnapshot) and e.time >= since]

    def messages(self, topic: str, since: float = 0.0) -> list[MessageArrival]:
        return [e for e in self.events
                if isinstance(e, MessageArrival) and e.topic == topic and e.time >= since]

    def faults(self, kind: str = "") -> list[BlackBoxEvent]:
        return [e for e in self.events if isinstance(e, BlackBoxEvent) and kind in e.kind]


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[ThesisRobot]:
    """A robot of its own for tests that kill, stop or restart parts of it."""
    r = ThesisRobot(free_port(), log_dir=tmp_path / "logs")
    try:
        yield r.start()
    finally:
        r.stop()


@pytest.fixture(scope="module")
def shared_robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ThesisRobot]:
    """One robot for the tests that only add fake publishers beside it."""
    r = ThesisRobot(free_port(), log_dir=tmp_path_factory.mktemp("logs"))
    try:
        yield r.start()
    finally:
        r.stop()


SUBSCRIBED = Ros1Settings(rates_from_counters=False)
"""These tests are about the TCPROS subscription path; counters: test_ros1_bus_stats.py."""


def _watch(robot: ThesisRobot, topics: set[str], decoded: set[str] = frozenset(),
           settings: Ros1Settings | None = None) -> Watch:
    source = Ros1Source(robot.master_uri + "/", settings or SUBSCRIBED)
    source.start(Interest(topics=frozenset(topics), decoded=frozenset(decoded)))
    return Watch(source)


def _alive(graph: GraphSnapshot, node: str) -> bool | None:
    info = graph.nodes.get(node)
    return None if info is None else info.alive


def test_sigkilled_node_is_dead_within_a_second_and_followed_when_restarted(
        robot: ThesisRobot) -> None:
    w = _watch(robot, {IMAGE})
    try:
        assert w.until(lambda: len(w.messages(IMAGE)) >= 5)
        old_pid = robot.pid("/usb_cam")
        os.kill(old_pid, signal.SIGKILL)
        killed = time.time()
        assert w.until(lambda: any(_alive(g, "/usb_cam") is False for g in w.graphs(killed)))
        dead = next(g for g in w.graphs(killed) if _alive(g, "/usb_cam") is False)
        assert dead.time - killed <= 1.0
        assert "/usb_cam" in robot.system_node_names()  # the master still lists it
        assert w.faults("node_dead")[0].component == "/usb_cam"
        assert any("lost /usb_cam/image_raw from /usb_cam" in f.message
                   for f in w.faults("connection_fault"))

        robot.nodes["/usb_cam"].wait(timeout=5)
        robot.start_node("/usb_cam")
        restarted = time.time()
        assert w.until(lambda: len(w.messages(IMAGE, restarted)) >= 5, timeout=15)
        graph = w.graphs()[-1]
        assert graph.nodes["/usb_cam"].alive
        assert graph.nodes["/usb_cam"].pid == robot.pid("/usb_cam") != old_pid
        assert [f.component for f in w.faults("subscribed")] == [IMAGE]
    finally:
        w.source.close()


def test_stopped_node_stops_answering_and_resumes(robot: ThesisRobot) -> None:
    w = _watch(robot, {"/audio"})
    pid = robot.pid("/audio_capture")
    try:
        assert w.until(lambda: len(w.messages("/audio")) >= 5)
        os.kill(pid, signal.SIGSTOP)
        stopped = time.time()
        assert w.until(lambda: any(_alive(g, "/audio_capture") is False
                                   for g in w.graphs(stopped)))
        assert "timed out" in w.faults("node_dead")[0].message
        time.sleep(0.5)
        os.kill(pid, signal.SIGCONT)
        resumed = time.time()
        assert w.until(lambda: len(w.messages("/audio", resumed)) >= 10)
        assert w.until(lambda: _alive(w.graphs()[-1], "/audio_capture") is True)
    finally:
        os.kill(pid, signal.SIGCONT)
        w.source.close()


def test_master_restart_is_survived_and_data_keeps_flowing(robot: ThesisRobot) -> None:
    w = _watch(robot, {"/signal"}, {"/signal"})
    try:
        assert w.until(lambda: len(w.messages("/signal")) >= 5)
        robot.stop_master()
        stopped = time.time()
        assert w.until(lambda: len(w.faults("master_lost")) == 1)
        # peers talk directly: the black box keeps reading while the master is away
        assert w.until(lambda: len(w.messages("/signal", stopped + 0.5)) >= 10)
        graph = w.graphs()[-1]
        assert graph.nodes["/Signal_generator"].alive
        assert graph.topics["/signal"].publishers == ("/Signal_generator",)

        robot.start_master()
        assert w.until(lambda: len(w.faults("master_back")) == 1)
        back = time.time()
        assert w.until(lambda: len(w.graphs(back)) >= 3)
        graph = w.graphs()[-1]
        # rospy nodes do not register again with a new master; they are still running
        assert "/Signal_generator" not in robot.system_node_names()
        assert graph.nodes["/Signal_generator"].alive
        assert graph.topics["/signal"].publishers == ("/Signal_generator",)
        assert graph.topics["/signal"].type == "std_msgs/Float64"
        assert 14.5 <= w.messages("/signal", back)[-1].value.data <= 15.5
    finally:
        w.source.close()


class FakePublisher:
    """A node that exists only as a slave API and a TCP port, registered by hand.

    ``serve(conn)`` decides what the connection gets after the subscriber's header.
    """

    def __init__(self, master: str, topic: str, serve: Callable[[socket.socket], None],
                 name: str = "/garbage") -> None:
        self.name, self.topic, self.serve = name, topic, serve
        self.connections = 0
        self.tcp = socket.create_server(("127.0.0.1", 0))
        self.tcp.settimeout(0.2)
        self.api = SimpleXMLRPCServer(("127.0.0.1", 0), logRequests=False, allow_none=True)
        self.api.register_function(lambda caller: [1, "", os.getpid()], "getPid")
        self.api.register_function(
            lambda caller, topic, protocols: [1, "", ["TCPROS", "127.0.0.1",
                                                      self.tcp.getsockname()[1]]],
            "requestTopic")
        self.uri = f"http://127.0.0.1:{self.api.server_address[1]}/"
        self._stop = threading.Event()
        self.held: list[socket.socket] = []
        self._threads = [threading.Thread(target=self.api.serve_forever, daemon=True),
                         threading.Thread(target=self._accept, daemon=True)]
        for t in self._threads:
            t.start()
        code, msg, _ = xmlrpc.client.ServerProxy(master).registerPublisher(
            name, topic, "std_msgs/Float64", self.uri)
        assert code == 1, msg

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.tcp.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            conn.settimeout(2.0)
            (size,) = struct.unpack("<I", conn.recv(4))
            while size:
                size -= len(conn.recv(size))
            self.held.append(conn)
            self.serve(conn)

    def stop_api(self) -> None:
        self.api.shutdown()
        self.api.server_close()

    def close(self) -> None:
        self._stop.set()
        self.tcp.close()
        for c in self.held:
            c.close()


def _float_header(topic: str) -> bytes:
    return encode_header({"type": "std_msgs/Float64", "md5sum": "fdb28210bfa9d7c91146260178d9a584",
                          "message_definition": "float64 data\n", "callerid": "/garbage",
                          "topic": topic})


GARBAGE = {
    "header": lambda c: c.sendall(struct.pack("<I", 9) + b"\x05\x00\x00\x00no-eq"),
    "huge_header": lambda c: c.sendall(struct.pack("<I", 0x7FFFFFFF)),
    "length": lambda c: c.sendall(_float_header("/junk_length") + struct.pack("<I", 0xFFFFFFF0)),
    "close": lambda c: c.close(),
}


@pytest.mark.parametrize("mode", sorted(GARBAGE))
def test_garbage_publisher_is_survived_with_a_reason_and_retried_with_backoff(
        shared_robot: ThesisRobot, mode: str, receive_path: str) -> None:
    junk = f"/junk_{mode}"
    fake = FakePublisher(shared_robot.master_uri, junk, GARBAGE[mode], f"/garbage_{mode}")
    w = _watch(shared_robot, {junk, "/signal"}, {junk},
               Ros1Settings(backoff_min=0.1, backoff_max=0.4, rates_from_counters=False))
    try:
        assert w.until(lambda: fake.connections >= 3 and len(w.messages("/signal")) >= 15)
        reasons = [f.message for f in w.faults("connection_fault") if f.component == junk]
        expected = {"header": "field without '='", "huge_header": "exceeds 1048576 bytes",
                    "length": "exceeds the cap of 67108864 bytes",
                    "close": "closed by the publisher"}[mode]
        assert expected in reasons[0]
        assert f"from /garbage_{mode}" in reasons[0]
        # the same fault again is retried quietly, not logged on every attempt
        assert len(reasons) <= 2
        # backoff: 3 s of retries at 0.1, 0.2, 0.4, 0.4 ... s apart, not a busy loop
        assert fake.connections < 15
        assert w.messages(junk) == []
        assert {m.publisher for m in w.messages("/signal")} == {"/Signal_generator"}
    finally:
        w.source.close()
        fake.close()


def test_oversized_messages_respect_the_per_topic_cap(shared_robot: ThesisRobot) -> None:
    source = Ros1Source(shared_robot.master_uri + "/", SUBSCRIBED)
    source.start(Interest(topics=frozenset({IMAGE}), max_message_bytes={IMAGE: 100_000}))
    w = Watch(source)
    try:
        assert w.until(lambda: len(w.faults("connection_fault")) >= 1)
        assert "exceeds the cap of 100000 bytes for /usb_cam/image_raw" in \
            w.faults("connection_fault")[0].message
        assert w.messages(IMAGE) == []
    finally:
        source.close()


def test_half_open_connection_is_closed_once_the_publisher_is_gone(
        shared_robot: ThesisRobot, receive_path: str) -> None:
    """The peer keeps the socket open but sends nothing and its API no longer answers."""
    fake = FakePublisher(shared_robot.master_uri, "/quiet",
                         lambda c: c.sendall(_float_header("/quiet") + struct.pack("<I", 8)
                                             + struct.pack("<d", 1.5)), "/silent")
    w = _watch(shared_robot, {"/quiet"},
               settings=Ros1Settings(idle_grace=1.0, rates_from_counters=False))
    try:
        assert w.until(lambda: len(w.messages("/quiet")) == 1)
        fake.stop_api()
        assert w.until(lambda: any("half-open" in f.message for f in w.faults()))
        conn = fake.held[0]
        conn.settimeout(3.0)
        assert conn.recv(1) == b""  # the black box closed its end
        graph = w.graphs()[-1]
        assert graph.nodes["/silent"].alive is False
    finally:
        w.source.close()
        fake.close()
