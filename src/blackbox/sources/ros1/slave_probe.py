"""The liveness probe: ``getPid`` on every node several times a second, from one thread.

Every node is asked for its pid through its own slave API each graph round (a node killed
with SIGKILL stays registered with the master, and a stopped one still accepts TCP
connections), so the probe is the black box's most frequent network work, and each probe
is also work for the robot's node. Hence:

* one non-blocking socket per node and one selector, no thread or HTTP client per call;
* HTTP/1.1 keep-alive: rospy (``protocol_version = 'HTTP/1.1'``) and roscpp serve a kept
  connection from one thread, where an HTTP/1.0 probe made every rospy node accept a
  connection and start a thread for it several times a second. A kept connection the node
  closed while idle is reopened at once within the same deadline; one that timed out is
  dropped (a late answer would be read as the next one's);
* extra calls (the publishers' ``getBusStats``) ride along in one ``system.multicall``.
  A batch that fails as a whole (a server without it, or rospy failing to encode a byte
  counter past 2**31) is followed by a plain ``getPid`` within the same deadline.
"""

from __future__ import annotations

import errno
import functools
import os
import selectors
import socket
import time
import xmlrpc.client
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, cast
from urllib.parse import urlsplit

from blackbox.errors import BlackBoxError
from blackbox.sources.ros1.master import CALLER_ID, RosApiError, describe_error, ros_value

_MAX_REPLY = 256 * 1024
_GET_PID = xmlrpc.client.dumps((CALLER_ID,), "getPid").encode()


@dataclass(frozen=True, slots=True)
class NodeReply:
    """One node's answers in a probe round: its pid (or why not) and the extra calls'.

    ``extra`` maps each extra method to its value or a :class:`RosApiError`. When the
    batch failed as a whole (``multicall`` is then ``False``), the pid was asked alone and
    every extra method has the batch's error."""

    pid: int | RosApiError
    extra: dict[str, Any] = field(default_factory=dict)
    multicall: bool = True


class _BatchFault(BlackBoxError):
    """``system.multicall`` as a whole was answered with a fault."""


@functools.cache
def _multicall_body(methods: tuple[str, ...]) -> bytes:
    calls = [{"methodName": m, "params": [CALLER_ID]} for m in ("getPid", *methods)]
    return xmlrpc.client.dumps((calls,), "system.multicall").encode()


def _address(uri: str) -> tuple[str, int, str]:
    parts = urlsplit(uri)
    if not parts.hostname or parts.port is None:
        raise RosApiError(f"not an http://HOST:PORT/ URI: {uri!r}")
    return parts.hostname, parts.port, parts.path or "/"


def _request(uri: str, body: bytes) -> bytes:
    host, port, path = _address(uri)
    return (f"POST {path} HTTP/1.1\r\nHost: {host}:{port}\r\nUser-Agent: blackbox\r\n"
            f"Content-Type: text/xml\r\nContent-Length: {len(body)}\r\n\r\n").encode() + body


@dataclass(frozen=True, slots=True)
class _Response:
    body: bytes
    keep_alive: bool


def _complete_response(what: str, data: bytes | bytearray) -> _Response | None:
    """The response in ``data`` once all of it is there (``None`` until then)."""
    end = data.find(b"\r\n\r\n")
    if end < 0:
        return None
    lines = bytes(data[:end]).split(b"\r\n")
    if not lines[0].startswith(b"HTTP/1.") or b" 200 " not in lines[0] + b" ":
        raise RosApiError(f"{what}: not an HTTP 200 reply: {bytes(data[:60])!r}")
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(b":")
        headers[name.strip().lower()] = value.strip().lower()
    length = headers.get(b"content-length")
    if length is None or not length.isdigit():
        raise RosApiError(f"{what}: reply without a Content-Length")
    if len(data) < end + 4 + int(length):
        return None
    keep = lines[0].startswith(b"HTTP/1.1") and headers.get(b"connection") != b"close"
    return _Response(bytes(data[end + 4:end + 4 + int(length)]), keep)


def _pid_of(what: str, value: Any) -> int | RosApiError:
    if isinstance(value, RosApiError):
        return value
    if not isinstance(value, int) or isinstance(value, bool):
        return RosApiError(f"{what}: not a pid: {str(value)[:40]!r}")
    return value


def _loads(what: str, body: bytes) -> Any:
    try:
        (value,), _ = xmlrpc.client.loads(body)
    except xmlrpc.client.Fault as fault:
        raise _BatchFault(f"{what}: fault {fault.faultCode}: "
                          f"{str(fault.faultString)[:120]}") from None
    except Exception as exc:  # garbage on the wire can raise anything from the parser
        raise RosApiError(f"{what}: malformed reply ({describe_error(exc)})") from None
    return value


def parse_reply(uri: str, body: bytes, methods: tuple[str, ...]) -> NodeReply:
    """A node's answer to ``getPid`` (no ``methods``) or to ``system.multicall`` of getPid
    plus ``methods`` (each answer ``[reply]`` or a fault struct); raises
    :class:`RosApiError`, or :class:`_BatchFault` when a batch failed as a whole."""
    if not methods:
        what = f"getPid on {uri}"
        try:
            value = _loads(what, body)
        except _BatchFault as fault:
            raise RosApiError(str(fault)) from None
        pid = _pid_of(what, ros_value(what, value))
        if isinstance(pid, RosApiError):
            raise pid
        return NodeReply(pid)
    what = f"system.multicall on {uri}"
    answers = _loads(what, body)
    names = ("getPid", *methods)
    if not (isinstance(answers, list) and len(answers) == len(names)):
        raise RosApiError(f"{what}: unexpected reply {str(answers)[:80]!r}")
    values: list[Any] = []
    for name, answer in zip(names, answers, strict=True):
        call = f"{name} on {uri}"
        if isinstance(answer, list) and len(answer) == 1:
            values.append(ros_value(call, answer[0]))
        else:
            values.append(RosApiError(f"{call}: {str(answer)[:80]!r}"))
    return NodeReply(_pid_of(f"getPid on {uri}", values[0]),
                     dict(zip(methods, values[1:], strict=True)))


@dataclass(slots=True)
class _Exchange:
    """One request in flight on one socket."""

    name: str
    uri: str
    methods: tuple[str, ...]
    sock: socket.socket
    kept: bool
    """The socket was kept from an earlier round (the node may have closed it since)."""
    request: bytes
    reply: bytearray = field(default_factory=bytearray)


class SlaveProbe:
    """Asks many nodes for their pid (plus extra calls) at once, keeping connections.

    Not thread-safe: one graph thread calls :meth:`probe`."""

    def __init__(self) -> None:
        self._kept: dict[str, tuple[str, socket.socket]] = {}
        self.connects = 0
        """Connections opened so far (kept ones are reused; tests and benchmarks read it)."""

    def close(self) -> None:
        for _, sock in self._kept.values():
            sock.close()
        self._kept.clear()

    def probe(self, uris: Mapping[str, str], timeout: float,
              extra: Mapping[str, tuple[str, ...]] | None = None) -> dict[str, NodeReply]:
        """``getPid`` on every node of ``uris`` within ``timeout`` seconds, plus the
        ``extra`` methods (called with the caller id) of some nodes in the same request."""
        for name in [n for n, (uri, _) in self._kept.items() if uris.get(n) != uri]:
            self._kept.pop(name)[1].close()
        return _Round(self, extra or {}).run(uris, timeout)

    def take(self, name: str, uri: str, fresh: bool) -> tuple[socket.socket, bool] | RosApiError:
        """``name``'s kept socket (out of the pool) unless ``fresh``, else a new connecting
        one; with whether it was kept."""
        kept = self._kept.pop(name, None)
        if kept is not None and not fresh:
            return kept[1], True
        if kept is not None:
            kept[1].close()
        try:
            host, port, _ = _address(uri)
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
            sock = socket.socket(infos[0][0], socket.SOCK_STREAM)
        except RosApiError as exc:
            return exc
        except OSError as exc:
            return RosApiError(f"getPid on {uri}: {describe_error(exc)}")
        sock.setblocking(False)
        self.connects += 1
        err = sock.connect_ex(infos[0][4])
        if err not in (0, errno.EINPROGRESS):
            sock.close()
            return RosApiError(f"getPid on {uri}: {os.strerror(err).lower()}")
        return sock, False

    def keep(self, name: str, uri: str, sock: socket.socket) -> None:
        self._kept[name] = (uri, sock)


class _Round:
    """One probe round: every request in flight under one selector and one deadline."""

    def __init__(self, probe: SlaveProbe, extra: Mapping[str, tuple[str, ...]]) -> None:
        self.probe = probe
        self.extra = extra
        self.results: dict[str, NodeReply] = {}
        self.faults: dict[str, RosApiError] = {}
        self.sel = selectors.DefaultSelector()
        self.pending: dict[socket.socket, _Exchange] = {}

    def run(self, uris: Mapping[str, str], timeout: float) -> dict[str, NodeReply]:
        try:
            for name, uri in uris.items():
                self.start(name, uri, self.extra.get(name, ()), fresh=False)
            deadline = time.monotonic() + timeout
            while self.pending:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                for key, mask in self.sel.select(left):
                    self.step(self.pending[cast(socket.socket, key.fileobj)], mask)
            for ex in list(self.pending.values()):
                self.release(ex, keep=False)
                self.answer(ex.name, RosApiError(f"getPid on {ex.uri}: no answer "
                                                 "(timed out)"))
        finally:
            self.sel.close()
        return self.results

    def answer(self, name: str, pid: int | RosApiError) -> None:
        fault = self.faults.get(name)
        self.results[name] = NodeReply(pid) if fault is None else NodeReply(
            pid, dict.fromkeys(self.extra.get(name, ()), fault), multicall=False)

    def start(self, name: str, uri: str, methods: tuple[str, ...], fresh: bool) -> None:
        try:
            request = _request(uri, _multicall_body(methods) if methods else _GET_PID)
        except RosApiError as exc:
            self.answer(name, exc)
            return
        taken = self.probe.take(name, uri, fresh)
        if isinstance(taken, RosApiError):
            self.answer(name, taken)
            return
        sock, kept = taken
        self.pending[sock] = _Exchange(name, uri, methods, sock, kept, request)
        self.sel.register(sock, selectors.EVENT_WRITE)

    def release(self, ex: _Exchange, keep: bool) -> None:
        self.sel.unregister(ex.sock)
        del self.pending[ex.sock]
        if keep:
            self.probe.keep(ex.name, ex.uri, ex.sock)
        else:
            ex.sock.close()

    def step(self, ex: _Exchange, mask: int) -> None:
        try:
            if mask & selectors.EVENT_WRITE:
                err = ex.sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
                if err:
                    raise ConnectionError(err, os.strerror(err).lower())
                ex.sock.sendall(ex.request)
                self.sel.modify(ex.sock, selectors.EVENT_READ)
                return
            chunk = ex.sock.recv(65536)
        except OSError as exc:
            self.failed(ex, describe_error(exc))
            return
        if not chunk:
            self.failed(ex, "connection closed without a reply")
            return
        ex.reply += chunk
        what = f"getPid on {ex.uri}"
        try:
            if len(ex.reply) > _MAX_REPLY:
                raise RosApiError(f"{what}: reply larger than {_MAX_REPLY} bytes")
            response = _complete_response(what, ex.reply)
            if response is None:
                return
            self.release(ex, keep=response.keep_alive)
            outcome = parse_reply(ex.uri, response.body, ex.methods)
        except RosApiError as exc:
            if ex.sock in self.pending:
                self.release(ex, keep=False)
            self.answer(ex.name, exc)
            return
        except _BatchFault as fault:
            self.faults[ex.name] = RosApiError(str(fault))
            self.start(ex.name, ex.uri, (), fresh=False)
            return
        if ex.methods:  # the batch itself answered (a faulted one is retried without)
            self.results[ex.name] = outcome
        else:
            self.answer(ex.name, outcome.pid)

    def failed(self, ex: _Exchange, error: str) -> None:
        """A kept connection the node closed while idle gets one fresh connection at once;
        any other failure is the node's answer for this round."""
        self.release(ex, keep=False)
        if ex.kept and not ex.reply:
            self.start(ex.name, ex.uri, ex.methods, fresh=True)
        else:
            self.answer(ex.name, RosApiError(f"getPid on {ex.uri}: {error}"))
