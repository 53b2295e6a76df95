"""``Ros1TopicPublisher``: one ROS 1 topic published without rospy.

A ROS 1 publisher is two small servers and two master calls:

* a slave API (XML-RPC) that the master and subscribers call: ``requestTopic`` hands out
  the TCPROS endpoint; ``getPid``, ``getBusInfo``, ``getBusStats``, ``getSubscriptions``,
  ``getPublications``, ``getMasterUri``, ``publisherUpdate``, ``paramUpdate`` and
  ``shutdown`` answer what ``rosnode`` and the master ask;
* a TCPROS server: a subscriber connects, sends its connection header (``callerid``,
  ``topic``, ``md5sum``, ``type``), gets ours (``callerid``, ``topic``, ``type``, ``md5sum``,
  ``message_definition``, ``latching``) and then every message as a 4-byte little-endian
  length and the serialized bytes;
* ``registerPublisher`` with the master on start (retried, and repeated when the master
  forgets the node, e.g. after a restart) and ``unregisterPublisher`` on close.

Both servers bind ``host`` (127.0.0.1 by default) on port 0. Messages go out from one
writer thread, so :meth:`publish` never blocks its caller: a subscriber that does not take
its data within ``send_timeout`` seconds, disconnects or sends garbage is dropped and
counted, and nothing else notices.
"""

from __future__ import annotations

import logging
import os
import socket
import socketserver
import threading
import xmlrpc.server
from dataclasses import dataclass, field
from typing import Any

from blackbox.sources.ros1.master import RosApi, RosApiError
from blackbox.sources.ros1.wire import HeaderError, encode_header, frame, read_header

log = logging.getLogger("blackbox.output.ros1")

__all__ = ["Ros1TopicPublisher"]

_MAX_HEADER = 64 * 1024


@dataclass(slots=True)
class _Connection:
    id: int
    sock: socket.socket
    caller_id: str
    bytes_sent: int = 0
    messages: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    """Held while writing, so frames from two threads never interleave."""


class _XmlRpcServer(socketserver.ThreadingMixIn, xmlrpc.server.SimpleXMLRPCServer):
    daemon_threads = True
    allow_reuse_address = True


class Ros1TopicPublisher:
    """Publishes serialized ROS 1 messages of one type on one topic (see the module)."""

    def __init__(self, master_uri: str, caller_id: str, topic: str, msg_type: str,
                 md5sum: str, definition: str, *, latching: bool = True,
                 host: str = "127.0.0.1", send_timeout: float = 1.0,
                 handshake_timeout: float = 2.0, register_period: float = 2.0,
                 master_timeout: float = 1.0) -> None:
        self.master_uri = master_uri
        self.caller_id = caller_id
        self.topic = topic
        self.msg_type = msg_type
        self.md5sum = md5sum
        self.definition = definition
        self.latching = latching
        self.host = host
        self.send_timeout = send_timeout
        self.handshake_timeout = handshake_timeout
        self.register_period = register_period
        self.master_timeout = master_timeout
        self.registered = False
        self.rejected = 0
        """Subscriber connections refused (bad header, wrong topic or type, timeout)."""
        self.dropped = 0
        """Subscribers dropped after the handshake (gone, or too slow)."""
        self._connections: dict[int, _Connection] = {}
        self._next_id = 1
        self._latched: bytes | None = None
        self._pending: bytes | None = None
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._tcp = socket.create_server((host, 0))
        self._tcp.settimeout(0.5)
        self.tcp_port: int = self._tcp.getsockname()[1]
        self._xmlrpc = _XmlRpcServer((host, 0), logRequests=False, allow_none=True)
        self.uri = f"http://{host}:{self._xmlrpc.server_address[1]}/"
        for name in ("requestTopic", "getPid", "getBusInfo", "getBusStats",
                     "getSubscriptions", "getPublications", "getMasterUri", "shutdown",
                     "publisherUpdate", "paramUpdate"):
            self._xmlrpc.register_function(getattr(self, "_api_" + name), name)

    # ---- life cycle --------------------------------------------------------------------------

    def start(self) -> None:
        for target, name in ((self._xmlrpc.serve_forever, "ros1-pub-xmlrpc"),
                             (self._accept_loop, "ros1-pub-accept"),
                             (self._write_loop, "ros1-pub-write"),
                             (self._register_loop, "ros1-pub-register")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def close(self) -> None:
        """Unregister from the master, stop both servers and close every connection."""
        if self._stop.is_set():
            return
        self._stop.set()
        with self._lock:
            self._wake.notify_all()
        if self.registered:
            try:
                RosApi(self.master_uri, self.master_timeout).call(
                    "unregisterPublisher", self.caller_id, self.topic, self.uri)
            except RosApiError as exc:
                log.warning("could not unregister %s from the master: %s", self.topic, exc)
            self.registered = False
        self._xmlrpc.shutdown()
        self._xmlrpc.server_close()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._tcp.close()
        with self._lock:
            for conn in self._connections.values():
                _close(conn.sock)
            self._connections.clear()

    # ---- publishing --------------------------------------------------------------------------

    def publish(self, data: bytes) -> None:
        """Queue one serialized message for every subscriber; never blocks on them."""
        with self._lock:
            if self.latching:
                self._latched = data
            self._pending = data
            self._wake.notify_all()

    def subscriber_count(self) -> int:
        with self._lock:
            return len(self._connections)

    def _write_loop(self) -> None:
        while True:
            with self._lock:
                while self._pending is None and not self._stop.is_set():
                    self._wake.wait()
                if self._stop.is_set():
                    return
                data, self._pending = self._pending, None
                connections = list(self._connections.values())
            assert data is not None
            framed = frame(data)
            for conn in connections:
                self._send(conn, framed)

    def _send(self, conn: _Connection, frame: bytes, locked: bool = False) -> bool:
        try:
            if locked:
                conn.sock.sendall(frame)
            else:
                with conn.lock:
                    conn.sock.sendall(frame)
        except OSError as exc:  # gone, reset or too slow: drop it, keep publishing
            with self._lock:
                if self._connections.pop(conn.id, None) is not None:
                    self.dropped += 1
            _close(conn.sock)
            log.info("dropped subscriber %s of %s: %s", conn.caller_id, self.topic, exc)
            return False
        conn.bytes_sent += len(frame)
        conn.messages += 1
        return True

    # ---- TCPROS server -----------------------------------------------------------------------

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                sock, _ = self._tcp.accept()
            except TimeoutError:
                continue
            except OSError:
                return  # closed
            threading.Thread(target=self._handshake, args=(sock,), name="ros1-pub-handshake",
                             daemon=True).start()

    def _handshake(self, sock: socket.socket) -> None:
        try:
            sock.settimeout(self.handshake_timeout)
            fields = read_header(sock, _MAX_HEADER)
            error = self._check(fields)
            if error is not None:
                sock.sendall(encode_header({"error": error}))
                raise HeaderError(error)
            sock.sendall(encode_header({
                "callerid": self.caller_id, "topic": self.topic, "type": self.msg_type,
                "md5sum": self.md5sum, "message_definition": self.definition,
                "latching": "1" if self.latching else "0"}))
            sock.settimeout(self.send_timeout)
            if fields.get("tcp_nodelay") == "1":
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except (OSError, HeaderError, ValueError, UnicodeError) as exc:
            with self._lock:
                self.rejected += 1
            _close(sock)
            log.info("refused a subscriber of %s: %s", self.topic, exc)
            return
        with self._lock:
            if self._stop.is_set():
                _close(sock)
                return
            conn = _Connection(self._next_id, sock, fields.get("callerid", "?"))
            self._next_id += 1
            self._connections[conn.id] = conn
            # a late joiner gets the last array at once, unless the writer is about to send
            # it anyway; holding its lock keeps the writer's next frame behind this one
            latched = self._latched if self._pending is None else None
            conn.lock.acquire()
        try:
            if latched is not None:
                self._send(conn, frame(latched), locked=True)
        finally:
            conn.lock.release()

    def _check(self, fields: dict[str, str]) -> str | None:
        if fields.get("topic") != self.topic:
            return f"{self.caller_id} does not publish {fields.get('topic')!r}"
        if fields.get("md5sum", "*") not in ("*", self.md5sum):
            return f"md5sum mismatch: {self.topic} is {self.msg_type} ({self.md5sum})"
        if fields.get("type", "*") not in ("*", self.msg_type):
            return f"type mismatch: {self.topic} is {self.msg_type}"
        return None

    # ---- master registration -----------------------------------------------------------------

    def _register_loop(self) -> None:
        api = RosApi(self.master_uri, self.master_timeout)
        while not self._stop.is_set():
            try:
                if self.registered and not self._listed(api.call("getSystemState",
                                                                 self.caller_id)):
                    log.warning("the master at %s forgot %s (restarted?): registering again",
                                self.master_uri, self.caller_id)
                    self.registered = False
                if not self.registered:
                    self._register(api)
            except RosApiError as exc:  # master unreachable: try again next round
                log.debug("registering %s: %s", self.topic, exc)
            self._stop.wait(self.register_period)

    def _listed(self, state: Any) -> bool:
        """Whether a ``getSystemState`` value lists us as a publisher of the topic."""
        publishers = state[0] if isinstance(state, list) and state else []
        return any(isinstance(entry, list) and len(entry) == 2 and entry[0] == self.topic
                   and isinstance(entry[1], list) and self.caller_id in entry[1]
                   for entry in publishers)

    def _register(self, api: RosApi) -> None:
        api.call("registerPublisher", self.caller_id, self.topic, self.msg_type, self.uri)
        if self._stop.is_set():
            api.call("unregisterPublisher", self.caller_id, self.topic, self.uri)
            return
        self.registered = True
        log.info("registered %s as publisher of %s with %s", self.caller_id, self.topic,
                 self.master_uri)

    # ---- slave API ---------------------------------------------------------------------------

    def _api_requestTopic(self, caller_id: str, topic: str, protocols: Any) -> list[Any]:
        if topic != self.topic:
            return [-1, f"{self.caller_id} does not publish {topic}", 0]
        if not isinstance(protocols, list) or not any(
                isinstance(p, list) and p and p[0] == "TCPROS" for p in protocols):
            return [0, "no supported protocol (only TCPROS)", 0]
        return [1, "ready", ["TCPROS", self.host, self.tcp_port]]

    def _api_getPid(self, caller_id: str) -> list[Any]:
        return [1, "", os.getpid()]

    def _api_getBusInfo(self, caller_id: str) -> list[Any]:
        with self._lock:
            return [1, "", [[c.id, c.caller_id, "o", "TCPROS", self.topic, True,
                             f"TCPROS connection on port {self.tcp_port} to [{c.caller_id}]"]
                            for c in self._connections.values()]]

    def _api_getBusStats(self, caller_id: str) -> list[Any]:
        with self._lock:
            conns = list(self._connections.values())
        sent = sum(c.bytes_sent for c in conns)
        return [1, "", [[[self.topic, sent, [[c.id, c.bytes_sent, c.messages, True]
                                             for c in conns]]], [], [0, 0, 0]]]

    def _api_getSubscriptions(self, caller_id: str) -> list[Any]:
        return [1, "", []]

    def _api_getPublications(self, caller_id: str) -> list[Any]:
        return [1, "", [[self.topic, self.msg_type]]]

    def _api_getMasterUri(self, caller_id: str) -> list[Any]:
        return [1, "", self.master_uri]

    def _api_publisherUpdate(self, caller_id: str, topic: str, publishers: Any) -> list[Any]:
        return [1, "", 0]  # we subscribe to nothing

    def _api_paramUpdate(self, caller_id: str, key: str, value: Any) -> list[Any]:
        return [1, "", 0]

    def _api_shutdown(self, caller_id: str, msg: str = "") -> list[Any]:
        """``rosnode kill`` or a node registered under our id: stop publishing (only that;
        the black box keeps watching)."""
        log.warning("%s asked the /diagnostics publisher to shut down: %s", caller_id, msg)
        threading.Thread(target=self.close, name="ros1-pub-shutdown", daemon=True).start()
        return [1, "shutdown", 0]


def _close(sock: socket.socket) -> None:
    sock.close()  # never raises for a socket.socket
