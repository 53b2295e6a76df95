"""A ROS 1 node that offers std_msgs/Float64 topics at rates rospy cannot reach, for benchmarks.

    python benchmarks/ros1/fast_publisher.py --master http://127.0.0.1:11311 --name /fast0 \\
        --topics 10 --rate 10000 [--prefix /fast0/t] [--tick 0.001] [--report 0.2]

A real ROS 1 publisher, without rospy: it registers every topic with the master
(``registerPublisher``), answers the slave API a subscriber and ``rosnode`` use
(``requestTopic``, ``getPid``, ``getBusInfo``, ``getBusStats``, ...) over XML-RPC and does
the TCPROS handshake on its own port. What makes it fast: the frames (length prefix and the
8 serialized bytes) are built once, and each tick writes everything due on a connection in
one ``send``. Pacing is by its own monotonic clock, never giving up lost time (each tick
sends every message due since the start, ``int(elapsed * rate)``), so the true rate over a
window is the nominal one as long as the CPU suffices and what was sent is known exactly.

Every ``--report`` seconds it prints ``<wall time> <messages written per topic>`` on stdout
(counted once a tick's frames are in the kernel's socket buffers of every connected
subscriber), the same format as ``paced_publisher.py``.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import socketserver
import struct
import sys
import threading
import time
import xmlrpc.client
import xmlrpc.server
from typing import Any

from blackbox.sources.ros1.wire import encode_header, read_header

TYPE = "std_msgs/Float64"
MD5 = "fdb28210bfa9d7c91146260178d9a584"
DEFINITION = "float64 data\n"
FRAME = struct.pack("<I", 8) + struct.pack("<d", 1.0)


class _XmlRpc(socketserver.ThreadingMixIn, xmlrpc.server.SimpleXMLRPCServer):
    daemon_threads = True


class FastPublisher:
    """Several Float64 topics of one node, served from one XML-RPC and one TCPROS port."""

    def __init__(self, master: str, name: str, topics: list[str]) -> None:
        self.master = master
        self.name = name
        self.topics = topics
        self.connections: dict[str, list[tuple[socket.socket, str, list[int]]]] = {
            t: [] for t in topics}
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.tcp = socket.create_server(("127.0.0.1", 0))
        self.tcp.settimeout(0.5)
        self.port = self.tcp.getsockname()[1]
        self.rpc = _XmlRpc(("127.0.0.1", 0), logRequests=False, allow_none=True)
        self.uri = f"http://127.0.0.1:{self.rpc.server_address[1]}/"
        for api in ("requestTopic", "getPid", "getBusInfo", "getBusStats", "getSubscriptions",
                    "getPublications", "getMasterUri", "shutdown", "publisherUpdate",
                    "paramUpdate"):
            self.rpc.register_function(getattr(self, api), api)

    def start(self) -> None:
        threading.Thread(target=self.rpc.serve_forever, daemon=True).start()
        threading.Thread(target=self._accept, daemon=True).start()
        master = xmlrpc.client.ServerProxy(self.master)
        for topic in self.topics:
            code, msg, _ = master.registerPublisher(self.name, topic, TYPE, self.uri)
            if code != 1:
                raise RuntimeError(f"registerPublisher {topic}: {msg}")

    def close(self) -> None:
        self.stop.set()
        master = xmlrpc.client.ServerProxy(self.master)
        for topic in self.topics:
            try:
                master.unregisterPublisher(self.name, topic, self.uri)
            except (OSError, xmlrpc.client.Error):
                break
        self.rpc.shutdown()
        self.tcp.close()

    # ---- TCPROS ------------------------------------------------------------------------------

    def _accept(self) -> None:
        while not self.stop.is_set():
            try:
                sock, _ = self.tcp.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            threading.Thread(target=self._handshake, args=(sock,), daemon=True).start()

    def _handshake(self, sock: socket.socket) -> None:
        try:
            sock.settimeout(2.0)
            fields = read_header(sock, 65536)
            topic = fields.get("topic", "")
            if topic not in self.connections:
                sock.sendall(encode_header({"error": f"{self.name} does not publish {topic}"}))
                sock.close()
                return
            sock.sendall(encode_header({"callerid": self.name, "topic": topic, "type": TYPE,
                                        "md5sum": MD5, "message_definition": DEFINITION,
                                        "latching": "0"}))
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(5.0)
        except Exception:
            sock.close()
            return
        with self.lock:
            self.connections[topic].append((sock, fields.get("callerid", "?"), [0, 0]))

    def send(self, frames: bytes, count: int) -> None:
        """Write ``count`` frames to every subscriber of every topic, one send each."""
        with self.lock:
            conns = [(t, c) for t, cs in self.connections.items() for c in cs]
        for topic, conn in conns:
            sock, _, stats = conn
            try:
                sock.sendall(frames)
            except OSError:
                with self.lock:
                    if conn in self.connections[topic]:
                        self.connections[topic].remove(conn)
                sock.close()
                continue
            stats[0] += count
            stats[1] += len(frames)

    # ---- slave API ---------------------------------------------------------------------------

    def requestTopic(self, caller: str, topic: str, protocols: Any) -> list[Any]:
        if topic not in self.connections:
            return [-1, f"not a publisher of {topic}", 0]
        return [1, "ready", ["TCPROS", "127.0.0.1", self.port]]

    def getPid(self, caller: str) -> list[Any]:
        return [1, "", os.getpid()]

    def getBusInfo(self, caller: str) -> list[Any]:
        with self.lock:
            return [1, "", [[i, c[1], "o", "TCPROS", t, True, ""]
                            for t, cs in self.connections.items() for i, c in enumerate(cs)]]

    def getBusStats(self, caller: str) -> list[Any]:
        with self.lock:
            pubs = [[t, sum(c[2][1] for c in cs), [[i, c[2][1], c[2][0], True]
                                                    for i, c in enumerate(cs)]]
                    for t, cs in self.connections.items()]
        return [1, "", [pubs, [], [0, 0, 0]]]

    def getSubscriptions(self, caller: str) -> list[Any]:
        return [1, "", []]

    def getPublications(self, caller: str) -> list[Any]:
        return [1, "", [[t, TYPE] for t in self.topics]]

    def getMasterUri(self, caller: str) -> list[Any]:
        return [1, "", self.master]

    def shutdown(self, caller: str, msg: str = "") -> list[Any]:
        self.stop.set()
        return [1, "", 0]

    def publisherUpdate(self, caller: str, topic: str, publishers: Any) -> list[Any]:
        return [1, "", 0]

    def paramUpdate(self, caller: str, key: str, value: Any) -> list[Any]:
        return [1, "", 0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--master", default=os.environ.get("ROS_MASTER_URI",
                                                           "http://127.0.0.1:11311/"))
    parser.add_argument("--name", required=True)
    parser.add_argument("--topics", type=int, default=1)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--prefix", default=None)
    parser.add_argument("--tick", type=float, default=0.001, help="seconds between writes")
    parser.add_argument("--report", type=float, default=0.2, help="seconds between reports")
    args = parser.parse_args(argv)
    # started in the background by a script, SIGINT arrives ignored: restore it
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    prefix = args.prefix or f"{args.name}/t"
    node = FastPublisher(args.master, args.name, [f"{prefix}{i}" for i in range(args.topics)])
    node.start()
    frames: dict[int, bytes] = {}
    t0 = time.monotonic()
    wall0 = time.time()
    sent = 0
    next_report = args.report
    try:
        while not node.stop.is_set():
            elapsed = time.monotonic() - t0
            due = int(elapsed * args.rate)
            if due > sent:
                k = due - sent
                data = frames.get(k)
                if data is None:
                    if len(frames) > 256:
                        frames.clear()
                    data = frames[k] = FRAME * k
                node.send(data, k)
                sent = due
            if elapsed >= next_report:
                next_report += args.report
                sys.stdout.write(f"{wall0 + elapsed:.6f} {sent}\n")
                sys.stdout.flush()
            delay = args.tick - (time.monotonic() - t0 - elapsed)
            if delay > 0:
                time.sleep(delay)
    except KeyboardInterrupt:
        pass
    finally:
        node.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
