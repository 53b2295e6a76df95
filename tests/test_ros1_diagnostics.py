"""``--publish-diagnostics`` on ROS 1: the black box registers as the publisher of
``/diagnostics`` with the master and serves TCPROS subscribers itself (no rospy).

The first tests talk TCPROS by hand (no roscore: the master is unreachable and the
publisher serves anyway); the last one runs the real thesis robot with a real rospy
subscriber and ``rostopic``."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from blackbox.app import RunOptions
from blackbox.output.diagnostics import DiagnosticStatusEntry
from blackbox.output.ros1_diagnostics import Ros1DiagnosticsSink
from blackbox.sources.ros1.wire import decode_header, encode_header
from conftest import black_box_running, wait_for

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from robot import ROS_PYTHON, ThesisRobot, free_port

ARRAY_MD5 = "60810da900de1dd6ddd437c3503511da"  # diagnostic_msgs/DiagnosticArray in Noetic
STORE = get_typestore(Stores.ROS1_NOETIC)


@pytest.fixture
def sink() -> Iterator[Ros1DiagnosticsSink]:
    box = Ros1DiagnosticsSink("r1", f"http://127.0.0.1:{free_port()}/")  # no master there
    try:
        yield box
    finally:
        box.close()


def _recv(sock: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("closed")
        buf += chunk
    return buf


def _frame(sock: socket.socket) -> bytes:
    (size,) = struct.unpack("<I", _recv(sock, 4))
    return _recv(sock, size)


def _subscribe(uri: str, **fields: str) -> tuple[socket.socket, dict[str, str]]:
    code, _, (proto, host, port) = xmlrpc.client.ServerProxy(uri).requestTopic(
        "/tester", "/diagnostics", [["TCPROS"]])
    assert (code, proto) == (1, "TCPROS")
    sock = socket.create_connection((host, port), timeout=5)
    header = {"callerid": "/tester", "topic": "/diagnostics", "md5sum": "*", "type": "*",
              "tcp_nodelay": "1", **fields}
    sock.sendall(encode_header(header))
    return sock, decode_header(_frame(sock))


def _statuses(level: int) -> list[DiagnosticStatusEntry]:
    return [DiagnosticStatusEntry(level, "blackbox/r1/audio_capture", "operational", "r1",
                                  (("activated /audio_capture", "ok"),))]


def test_a_subscriber_gets_the_header_and_ros1_serialized_arrays(
        sink: Ros1DiagnosticsSink) -> None:
    sink.publisher.publish(sink.serialize(100.5, _statuses(0)))
    sock, reply = _subscribe(sink.publisher.uri)
    with sock:
        assert reply["type"] == "diagnostic_msgs/DiagnosticArray"
        assert reply["md5sum"] == ARRAY_MD5
        assert reply["latching"] == "1" and "DiagnosticStatus" in reply["message_definition"]
        assert reply["callerid"].startswith("/blackbox_diagnostics_")
        latched = STORE.deserialize_ros1(_frame(sock), "diagnostic_msgs/msg/DiagnosticArray")
        assert latched.header.stamp.sec == 100 and latched.status[0].level == 0
        assert latched.status[0].values[0].key == "activated /audio_capture"
        sink.publisher.publish(sink.serialize(101.0, _statuses(2)))
        nxt = STORE.deserialize_ros1(_frame(sock), "diagnostic_msgs/msg/DiagnosticArray")
        assert nxt.status[0].level == 2 and nxt.header.seq == latched.header.seq + 1
    api = xmlrpc.client.ServerProxy(sink.publisher.uri)
    assert api.getPid("/t") == [1, "", os.getpid()]
    assert api.getPublications("/t") == [1, "", [["/diagnostics",
                                                   "diagnostic_msgs/DiagnosticArray"]]]
    assert api.getSubscriptions("/t") == [1, "", []]
    assert api.requestTopic("/t", "/other", [["TCPROS"]])[0] == -1
    assert api.requestTopic("/t", "/diagnostics", [["UDPROS"]])[0] == 0
    assert not sink.publisher.registered  # nobody to register with, served all the same


def test_garbage_and_vanishing_subscribers_do_not_disturb_the_publisher(
        sink: Ros1DiagnosticsSink) -> None:
    pub = sink.publisher
    pub.handshake_timeout = 0.5
    port = pub.tcp_port
    with socket.create_connection(("127.0.0.1", port)) as s:  # absurd header length
        s.sendall(b"\xff\xff\xff\x7f garbage")
    with socket.create_connection(("127.0.0.1", port)) as s:  # field without '='
        s.sendall(struct.pack("<I", 8) + struct.pack("<I", 4) + b"abcd")
    with socket.create_connection(("127.0.0.1", port)) as s:  # gone mid-header
        s.sendall(struct.pack("<I", 100) + b"\x05")
    silent = socket.create_connection(("127.0.0.1", port))  # says nothing at all
    wrong, reply = _subscribe(pub.uri, md5sum="0" * 32)
    wrong.close()
    assert "md5sum mismatch" in reply["error"]
    assert wait_for(lambda: pub.rejected == 5, 5), pub.rejected
    silent.close()
    # a subscriber that goes away after the handshake is dropped at the next message
    gone, _ = _subscribe(pub.uri)
    assert wait_for(lambda: pub.subscriber_count() == 1, 2)
    gone.close()
    good, _ = _subscribe(pub.uri)
    with good:
        for i in range(20):
            pub.publish(sink.serialize(200.0 + i, _statuses(i % 4)))
            time.sleep(0.01)
        assert wait_for(lambda: pub.dropped == 1 and pub.subscriber_count() == 1, 5)
        last = None
        good.settimeout(5)
        while last is None or last.header.stamp.sec != 219:
            last = STORE.deserialize_ros1(_frame(good), "diagnostic_msgs/msg/DiagnosticArray")
        bus = xmlrpc.client.ServerProxy(pub.uri).getBusInfo("/t")[2]
        assert [(c[1], c[2], c[4]) for c in bus] == [("/tester", "o", "/diagnostics")]


# ---- the real thesis robot --------------------------------------------------------------------

CONFIG = """
version: 1
robot: {id: thesis-robot}
observers:
  - {type: activated, node: /audio_capture, start_up_time: 1.0, every: 0.25}
  - {type: activated, node: /usb_cam, start_up_time: 1.0, every: 0.25}
  - {type: timeout, topic: /audio, timeout: 1.0}
"""

LISTENER = """
import json, sys, time, rospy
from diagnostic_msgs.msg import DiagnosticArray
def heard(msg):
    for s in msg.status:
        print(json.dumps([time.time(), s.name, s.level, s.message]), flush=True)
rospy.init_node("diagnostics_listener")
rospy.Subscriber("/diagnostics", DiagnosticArray, heard)
print(json.dumps(["ready"]), flush=True)
rospy.spin()
"""


def _topics(robot: ThesisRobot) -> list[str]:
    out = subprocess.run(["rostopic", "list", "-p"], env=robot.env, capture_output=True, text=True,
                         timeout=10, check=True)
    return out.stdout.split()


@pytest.mark.ros1
@pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")
def test_rospy_sees_ok_then_error_after_a_node_is_killed(tmp_path: Path) -> None:
    config = tmp_path / "observers.yaml"
    config.write_text(CONFIG)
    robot = ThesisRobot(free_port(), log_dir=tmp_path / "logs").start()
    heard: list[tuple[float, str, int, str]] = []
    listener = subprocess.Popen([ROS_PYTHON, "-c", LISTENER], env=robot.env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                start_new_session=True)

    def read() -> None:
        assert listener.stdout is not None
        for line in listener.stdout:
            row: list[Any] = json.loads(line)
            if len(row) == 4:
                heard.append((row[0], row[1], row[2], row[3]))

    threading.Thread(target=read, daemon=True).start()
    source = f"ros1://127.0.0.1:{robot.port}"
    try:
        # off by default: nothing on /diagnostics, the black box is not in the graph
        with black_box_running(RunOptions(config=config, source=source, live=False)):
            time.sleep(1.5)
            assert "/diagnostics" not in _topics(robot)
            nodes = subprocess.run(["rosnode", "list"], env=robot.env, capture_output=True,
                                   text=True, timeout=10, check=True).stdout.split()
            assert "/audio_capture" in nodes
            assert not [n for n in nodes if n.startswith("/blackbox")], nodes
        with black_box_running(RunOptions(config=config, source=source, live=False,
                                          publish_diagnostics=True)):
            name = "blackbox/thesis-robot/audio_capture"
            assert wait_for(lambda: any(n == name and lv == 0 for _, n, lv, _ in heard), 15), \
                heard[-3:]
            assert "/diagnostics" in _topics(robot)
            # a late joiner (rostopic, connecting through requestTopic) gets the latched array
            echo = subprocess.run(["rostopic", "echo", "-n", "1", "/diagnostics/status[0]"],
                                  env=robot.env, capture_output=True, text=True, timeout=10)
            assert "blackbox/thesis-robot/" in echo.stdout, echo.stdout + echo.stderr
            killed = time.time()
            os.kill(robot.pid("/audio_capture"), signal.SIGKILL)
            assert wait_for(lambda: any(t > killed and n == name and lv == 2
                                        for t, n, lv, _ in heard), 10), heard[-3:]
            error = next(m for t, n, lv, m in heard if t > killed and n == name and lv == 2)
            assert error.startswith("not operational") and "activated" in error
            cam = [lv for t, n, lv, _ in heard if t > killed and n.endswith("/usb_cam")]
            assert cam and cam[-1] == 0
        assert "/diagnostics" not in _topics(robot)  # unregistered on close
    finally:
        listener.terminate()
        listener.wait(timeout=5)
        robot.stop()


@pytest.mark.ros1
@pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")
def test_registers_again_after_a_master_restart_and_rosnode_kill_stops_only_publishing(
        tmp_path: Path) -> None:
    robot = ThesisRobot(free_port(), log_dir=tmp_path / "logs")
    robot.start_master()
    sink = Ros1DiagnosticsSink("r1", robot.master_uri)
    try:
        assert wait_for(lambda: "/diagnostics" in _topics(robot), 8)
        robot.stop_master()
        robot.start_master()
        assert wait_for(lambda: "/diagnostics" in _topics(robot), 8)
        subprocess.run(["rosnode", "kill", sink.publisher.caller_id], env=robot.env,
                       capture_output=True, timeout=10, check=True)
        assert wait_for(lambda: "/diagnostics" not in _topics(robot), 5)
        sink.publisher.publish(sink.serialize(1.0, _statuses(0)))  # harmless after a kill
    finally:
        sink.close()
        robot.stop()
