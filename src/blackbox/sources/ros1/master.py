"""The ROS 1 graph from the master's XML-RPC API, with liveness from each node itself.

The master only knows what nodes registered; a node killed with SIGKILL stays registered.
So every node is asked for its pid through its own slave API on every round: a node that
refuses or does not answer in time is reported dead whatever the master says. Nothing here
registers anything anywhere, so the robot never sees the black box in its graph.
"""

from __future__ import annotations

import errno
import functools
import http.client
import os
import selectors
import socket
import time
import xmlrpc.client
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, cast
from urllib.parse import urlsplit

from blackbox.events import GraphSnapshot, NodeInfo, TopicInfo
from blackbox.sources.ros1.callerid import is_black_box

CALLER_ID = "/blackbox"
"""The caller id the black box gives in XML-RPC calls; it is never registered."""

Report = Callable[[str, str, str], None]
"""``report(kind, component, message)``: a robot-side fault the black box noticed."""


class RosApiError(Exception):
    """An XML-RPC call failed: unreachable, timed out, malformed or answered with an error."""


class _TimeoutTransport(xmlrpc.client.Transport):
    def __init__(self, timeout: float) -> None:
        super().__init__()
        self._timeout = timeout

    def make_connection(self, host: Any) -> http.client.HTTPConnection:
        conn = super().make_connection(host)
        conn.timeout = self._timeout
        return conn


class RosApi:
    """One XML-RPC endpoint (the master or a node's slave API) with a per-call timeout.

    Not thread-safe: the transport keeps its HTTP connection between calls.
    """

    def __init__(self, uri: str, timeout: float) -> None:
        self.uri = uri
        self._proxy = xmlrpc.client.ServerProxy(uri, transport=_TimeoutTransport(timeout),
                                                allow_none=True)

    def call(self, method: str, *args: Any) -> Any:
        """Call ``method`` and return the value of a ``[code, message, value]`` reply."""
        try:
            reply = getattr(self._proxy, method)(*args)
        except (OSError, http.client.HTTPException, xmlrpc.client.Error) as exc:
            raise RosApiError(f"{method} on {self.uri}: {_describe(exc)}") from None
        except Exception as exc:  # garbage on the wire can raise anything from the parser
            raise RosApiError(f"{method} on {self.uri}: malformed reply ({_describe(exc)})"
                              ) from None
        if not (isinstance(reply, list) and len(reply) == 3 and isinstance(reply[0], int)):
            raise RosApiError(f"{method} on {self.uri}: unexpected reply {str(reply)[:80]!r}")
        code, message, value = reply
        if code != 1:
            raise RosApiError(f"{method} on {self.uri}: error {code}: {message}")
        return value


def _describe(exc: BaseException) -> str:
    if isinstance(exc, socket.timeout | TimeoutError):
        return "no answer (timed out)"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    text = str(exc) or type(exc).__name__
    return text[:160]


def host_of(uri: str) -> str | None:
    try:
        return urlsplit(uri).hostname
    except ValueError:
        return None


@dataclass(slots=True)
class SystemState:
    """``getSystemState`` as mappings from a topic to its node names."""

    publishers: dict[str, tuple[str, ...]] = field(default_factory=dict)
    subscribers: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def node_names(self) -> set[str]:
        names: set[str] = set()
        for group in (self.publishers, self.subscribers):
            for nodes in group.values():
                names.update(nodes)
        return names


def _topic_nodes(entries: Any) -> dict[str, tuple[str, ...]]:
    out: dict[str, tuple[str, ...]] = {}
    for entry in entries if isinstance(entries, list) else ():
        if (isinstance(entry, list) and len(entry) == 2 and isinstance(entry[0], str)
                and isinstance(entry[1], list)):
            out[entry[0]] = tuple(sorted(n for n in entry[1] if isinstance(n, str)))
    return out


class MasterClient:
    """The few master calls the black box needs; all read-only."""

    def __init__(self, uri: str, timeout: float = 1.0) -> None:
        self.uri = uri
        self._api = RosApi(uri, timeout)

    def system_state(self) -> SystemState:
        value = self._api.call("getSystemState", CALLER_ID)
        if not (isinstance(value, list) and len(value) == 3):
            raise RosApiError(f"getSystemState on {self.uri}: unexpected value")
        return SystemState(_topic_nodes(value[0]), _topic_nodes(value[1]))

    def topic_types(self) -> dict[str, str]:
        value = self._api.call("getTopicTypes", CALLER_ID)
        return {t: ty for t, ty in (e for e in value if isinstance(e, list) and len(e) == 2)
                if isinstance(t, str) and isinstance(ty, str)}

    def lookup_node(self, name: str) -> str:
        uri = self._api.call("lookupNode", CALLER_ID, name)
        if not isinstance(uri, str):
            raise RosApiError(f"lookupNode {name}: unexpected value")
        return uri


@dataclass(slots=True)
class NodeState:
    """What the poller knows about one node between rounds."""

    name: str
    uri: str | None = None
    alive: bool = False
    pid: int | None = None
    reason: str = "not yet probed"
    registered: bool = True
    unbatched_rounds: int = 0
    """Rounds left without extra calls: after ``system.multicall`` failed as a whole the
    node is asked for its pid alone for a while (``GraphPoller.batch_pause``)."""


def probe_pid(uri: str, timeout: float) -> int:
    """The pid a node reports through its own slave API (raises :class:`RosApiError`)."""
    pid = RosApi(uri, timeout).call("getPid", CALLER_ID)
    if not isinstance(pid, int):
        raise RosApiError(f"getPid on {uri}: not a pid: {pid!r}")
    return pid


class GraphPoller:
    """Builds :class:`GraphSnapshot` s from the master plus a liveness probe of every node.

    When the master is unreachable the last known topics are kept and the known nodes are
    still probed directly, so liveness keeps working through a master restart.
    """

    def __init__(self, master_uri: str, report: Report, probe_timeout: float = 0.5,
                 master_timeout: float = 1.0, max_workers: int = 8,
                 master_period: float = 1.0) -> None:
        self.master = MasterClient(master_uri, master_timeout)
        self._report = report
        self._probe_timeout = probe_timeout
        self._pool = ThreadPoolExecutor(max_workers=max_workers,
                                        thread_name_prefix="ros1-probe")
        self.nodes: dict[str, NodeState] = {}
        self.state = SystemState()
        self.types: dict[str, str] = {}
        self.master_ok: bool | None = None
        self._master_period = master_period
        self._next_master = 0.0
        self._registered: set[str] = set()
        self.batch_pause = 20
        """Rounds (about 9 s) a node whose batch failed is asked for its pid alone."""
        self.replies: dict[str, NodeReply] = {}
        """This round's replies of the nodes asked extra calls (see :meth:`refresh`)."""

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)

    def uri_of(self, node: str) -> str | None:
        st = self.nodes.get(node)
        return st.uri if st is not None else None

    def refresh(self, extra: Mapping[str, tuple[str, ...]] | None = None) -> None:
        """One round: probe every node, and ask the master every ``master_period`` s.

        ``extra``: slave API methods to call on some nodes in the same request as the
        probe; their answers are in :attr:`replies` until the next round.

        Liveness needs a fast probe; the graph's structure changes rarely, so the master
        is asked less often (and every round while it is unreachable).

        A node that is still alive but no longer registered (the master restarted; rospy
        and roscpp nodes do not register again) keeps its last known topics.
        """
        previous = self.state
        fresh = None
        now = time.monotonic()
        if now >= self._next_master or self.master_ok is not True:
            self._next_master = now + self._master_period
            fresh = self._refresh_master()
        if fresh is not None:
            self._registered = {n for n in fresh.node_names() if not is_black_box(n)}
        for name in self._registered - self.nodes.keys():
            self.nodes[name] = NodeState(name)
        for name, st in self.nodes.items():
            st.registered = name in self._registered
        self._probe(list(self.nodes.values()), extra or {})
        for name in [n for n, st in self.nodes.items() if not st.registered and not st.alive]:
            del self.nodes[name]
        if fresh is None:
            return
        orphans = {n for n, st in self.nodes.items() if st.alive and not st.registered}
        for group, old in ((fresh.publishers, previous.publishers),
                           (fresh.subscribers, previous.subscribers)):
            for topic, members in old.items():
                kept = orphans.intersection(members)
                if kept:
                    group[topic] = tuple(sorted(kept.union(group.get(topic, ()))))
        self.state = fresh

    def snapshot(self, now: float) -> GraphSnapshot:
        """The robot's graph; black boxes (this one's ``/diagnostics`` publisher, other
        black boxes) are left out: they are not part of the robot."""
        nodes = {n: NodeInfo(n, st.alive, st.pid if st.alive else None,
                             host_of(st.uri) if st.uri else None)
                 for n, st in sorted(self.nodes.items()) if not is_black_box(n)}
        topics: dict[str, TopicInfo] = {}
        for t in sorted(self.state.publishers.keys() | self.state.subscribers.keys()):
            pubs = tuple(n for n in self.state.publishers.get(t, ()) if not is_black_box(n))
            subs = tuple(n for n in self.state.subscribers.get(t, ()) if not is_black_box(n))
            if pubs or subs:
                topics[t] = TopicInfo(t, self.types.get(t, ""), pubs, subs)
        return GraphSnapshot(now, nodes, topics)

    def _refresh_master(self) -> SystemState | None:
        """The master's current state, or ``None`` (and a report) when it is unreachable."""
        try:
            state = self.master.system_state()
            topics = state.publishers.keys() | state.subscribers.keys()
            if not topics <= self.types.keys() or self.master_ok is not True:
                self.types.update(self.master.topic_types())
        except RosApiError as exc:
            if self.master_ok is not False:
                self._report("master_lost", self.master.uri,
                             f"ROS master unreachable, keeping the last known graph: {exc}")
            self.master_ok = False
            return None
        if self.master_ok is False:
            self._report("master_back", self.master.uri, "ROS master reachable again")
        self.master_ok = True
        return state

    def _probe(self, states: Iterable[NodeState],
               extra: Mapping[str, tuple[str, ...]]) -> None:
        states = list(states)
        batched = {n: m for n, m in extra.items()
                   if n in self.nodes and self.nodes[n].unbatched_rounds == 0}
        for st in states:
            st.unbatched_rounds = max(0, st.unbatched_rounds - 1)
        replies = probe_nodes({st.name: st.uri for st in states if st.uri},
                              self._probe_timeout, batched)
        self.replies = {n: r for n, r in replies.items() if r.extra}
        for name, reply in replies.items():
            if not reply.multicall:
                self.nodes[name].unbatched_rounds = self.batch_pause
        quick = {n: r.pid for n, r in replies.items()}
        slow = [(st, self._pool.submit(self._probe_one, st, quick.get(st.name)))
                for st in states if not isinstance(quick.get(st.name), int)]
        results: dict[str, int | Exception] = {
            n: r for n, r in quick.items() if isinstance(r, int)}
        for st, fut in slow:
            try:
                results[st.name] = fut.result()
            except Exception as exc:  # a probe must never take the poller down
                results[st.name] = exc
        for st in states:
            was_alive, old_reason = st.alive, st.reason
            result = results[st.name]
            if isinstance(result, int):
                st.pid, st.alive, st.reason = result, True, ""
            else:
                st.alive = False
                st.reason = (str(result) if isinstance(result, RosApiError)
                             else f"probe failed: {result!r}")
            if was_alive and not st.alive:
                self._report("node_dead", st.name, f"node {st.name} stopped answering its "
                             f"slave API: {st.reason}")
            elif st.alive and not was_alive and old_reason != "not yet probed":
                self._report("node_alive", st.name, f"node {st.name} answers again "
                             f"(pid {st.pid})")

    def _probe_one(self, st: NodeState, first: int | RosApiError | None) -> int:
        """After a failed quick probe: look the node up again (it may have restarted)."""
        first_error = first if isinstance(first, RosApiError) else None
        if self.master_ok is False or not st.registered:
            raise first_error or RosApiError(f"{st.name}: no slave URI known")
        try:
            uri = MasterClient(self.master.uri, self._probe_timeout).lookup_node(st.name)
        except RosApiError as exc:
            raise first_error or exc from None
        if uri == st.uri and first_error is not None:
            raise first_error
        if uri != st.uri:
            st.uri, st.unbatched_rounds = uri, 0
        return probe_pid(uri, self._probe_timeout)


_GET_PID = xmlrpc.client.dumps((CALLER_ID,), "getPid").encode()
_MAX_REPLY = 256 * 1024


class _BatchFault(Exception):
    """``system.multicall`` as a whole was answered with a fault: the server has none, or
    one answer could not be encoded (rospy cannot send an int over 2**31, and its byte
    counters pass that after 2 GB on one connection)."""


@dataclass(frozen=True, slots=True)
class NodeReply:
    """One node's answers in a probe round: its pid (or why not) and the extra calls'.

    ``extra`` maps each extra method to its value or a :class:`RosApiError`. When the
    batch failed as a whole (``multicall`` is then ``False``), the pid was asked alone and
    every extra method has the batch's error."""

    pid: int | RosApiError
    extra: dict[str, Any] = field(default_factory=dict)
    multicall: bool = True


@functools.cache
def _multicall_body(methods: tuple[str, ...]) -> bytes:
    calls = [{"methodName": m, "params": [CALLER_ID]} for m in ("getPid", *methods)]
    return xmlrpc.client.dumps((calls,), "system.multicall").encode()


def _http_request(uri: str, body: bytes) -> tuple[tuple[str, int], bytes]:
    parts = urlsplit(uri)
    if not parts.hostname or parts.port is None:
        raise RosApiError(f"not an http://HOST:PORT/ URI: {uri!r}")
    head = (f"POST {parts.path or '/'} HTTP/1.0\r\nHost: {parts.hostname}:{parts.port}\r\n"
            f"User-Agent: blackbox\r\nContent-Type: text/xml\r\n"
            f"Content-Length: {len(body)}\r\n\r\n")
    return (parts.hostname, parts.port), head.encode() + body


def _http_body(what: str, reply: bytes) -> bytes:
    head, sep, body = reply.partition(b"\r\n\r\n")
    if not sep or not head.startswith(b"HTTP/1.") or b" 200 " not in head.split(b"\r\n")[0]:
        raise RosApiError(f"{what}: not an HTTP 200 reply: {reply[:60]!r}")
    return body


def _ros_value(what: str, reply: Any) -> Any:
    """The value of a ``[code, message, value]`` reply, or a :class:`RosApiError`."""
    if not (isinstance(reply, list) and len(reply) == 3 and isinstance(reply[0], int)):
        return RosApiError(f"{what}: unexpected reply {str(reply)[:80]!r}")
    if reply[0] != 1:
        return RosApiError(f"{what}: error {reply[0]}: {reply[1]}")
    return reply[2]


def _pid_of(what: str, value: Any) -> int | RosApiError:
    if isinstance(value, RosApiError):
        return value
    if not isinstance(value, int) or isinstance(value, bool):
        return RosApiError(f"{what}: not a pid: {str(value)[:40]!r}")
    return value


def _parse_pid(uri: str, reply: bytes) -> int:
    what = f"getPid on {uri}"
    try:
        (value,), _ = xmlrpc.client.loads(_http_body(what, reply))
    except RosApiError:
        raise
    except Exception as exc:
        raise RosApiError(f"{what}: malformed reply ({_describe(exc)})") from None
    pid = _pid_of(what, _ros_value(what, value))
    if isinstance(pid, RosApiError):
        raise pid
    return pid


def _parse_multicall(uri: str, reply: bytes, methods: tuple[str, ...]) -> NodeReply:
    """``system.multicall`` of getPid plus ``methods``: each answer is ``[reply]`` or a
    fault struct. A fault for the whole call means the server cannot batch."""
    what = f"system.multicall on {uri}"
    try:
        (answers,), _ = xmlrpc.client.loads(_http_body(what, reply))
    except xmlrpc.client.Fault as fault:
        raise _BatchFault(f"{what}: fault {fault.faultCode}: "
                          f"{str(fault.faultString)[:120]}") from None
    except RosApiError:
        raise
    except Exception as exc:
        raise RosApiError(f"{what}: malformed reply ({_describe(exc)})") from None
    names = ("getPid", *methods)
    if not (isinstance(answers, list) and len(answers) == len(names)):
        raise RosApiError(f"{what}: unexpected reply {str(answers)[:80]!r}")
    values: list[Any] = []
    for name, answer in zip(names, answers, strict=True):
        call = f"{name} on {uri}"
        if isinstance(answer, list) and len(answer) == 1:
            values.append(_ros_value(call, answer[0]))
        else:
            values.append(RosApiError(f"{call}: {str(answer)[:80]!r}"))
    return NodeReply(_pid_of(f"getPid on {uri}", values[0]), dict(zip(methods, values[1:],
                                                                      strict=True)))


@dataclass(slots=True)
class _Exchange:
    name: str
    uri: str
    body: bytes
    methods: tuple[str, ...]
    request: bytes = b""
    reply: bytearray = field(default_factory=bytearray)


def _open(ex: _Exchange, sel: selectors.BaseSelector) -> socket.socket | RosApiError:
    try:
        address, ex.request = _http_request(ex.uri, ex.body)
        infos = socket.getaddrinfo(*address, type=socket.SOCK_STREAM)
        sock = socket.socket(infos[0][0], socket.SOCK_STREAM)
    except RosApiError as exc:
        return exc
    except OSError as exc:
        return RosApiError(f"getPid on {ex.uri}: {_describe(exc)}")
    sock.setblocking(False)
    err = sock.connect_ex(infos[0][4])
    if err not in (0, errno.EINPROGRESS):
        sock.close()
        return RosApiError(f"getPid on {ex.uri}: {os.strerror(err).lower()}")
    sel.register(sock, selectors.EVENT_WRITE)
    return sock


def _finish(ex: _Exchange) -> NodeReply | _BatchFault:
    try:
        if ex.methods:
            return _parse_multicall(ex.uri, bytes(ex.reply), ex.methods)
        return NodeReply(_parse_pid(ex.uri, bytes(ex.reply)))
    except RosApiError as exc:
        return NodeReply(exc)
    except _BatchFault as exc:
        return exc


def probe_nodes(uris: dict[str, str], timeout: float,
                extra: Mapping[str, tuple[str, ...]] | None = None) -> dict[str, NodeReply]:
    """``getPid`` on many nodes at once from one thread, each within ``timeout`` seconds,
    plus any ``extra`` methods (called with the caller id) per node in the same request.

    The liveness probe runs several times a second for every node, so it avoids a thread
    and an HTTP client per call: one non-blocking socket per node, one selector, and extra
    calls ride along as one ``system.multicall``. A server that cannot batch is asked for
    its pid alone within the same deadline and its reply says ``multicall=False``.
    """
    extra = extra or {}
    results: dict[str, NodeReply] = {}
    faults: dict[str, RosApiError] = {}
    sel = selectors.DefaultSelector()
    pending: dict[socket.socket, _Exchange] = {}

    def reply(name: str, pid: int | RosApiError) -> NodeReply:
        fault = faults.get(name)
        if fault is None:
            return NodeReply(pid)
        return NodeReply(pid, dict.fromkeys(extra.get(name, ()), fault), multicall=False)

    def start(ex: _Exchange) -> None:
        sock = _open(ex, sel)
        if isinstance(sock, RosApiError):
            results[ex.name] = reply(ex.name, sock)
        else:
            pending[sock] = ex

    try:
        for name, uri in uris.items():
            methods = extra.get(name, ())
            start(_Exchange(name, uri, _multicall_body(methods) if methods else _GET_PID,
                            methods))
        deadline = time.monotonic() + timeout
        while pending:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            for key, mask in sel.select(left):
                sock = cast(socket.socket, key.fileobj)
                ex = pending[sock]
                error: str | None = None
                try:
                    if mask & selectors.EVENT_WRITE:
                        err = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
                        if err:
                            error = os.strerror(err).lower()
                        else:
                            sock.sendall(ex.request)
                            sel.modify(sock, selectors.EVENT_READ)
                            continue
                    else:
                        chunk = sock.recv(65536)
                        if chunk and len(ex.reply) + len(chunk) <= _MAX_REPLY:
                            ex.reply += chunk
                            continue
                        if chunk:
                            error = f"reply larger than {_MAX_REPLY} bytes"
                except OSError as exc:
                    error = _describe(exc)
                sel.unregister(sock)
                sock.close()
                del pending[sock]
                if error is not None:
                    results[ex.name] = reply(ex.name,
                                             RosApiError(f"getPid on {ex.uri}: {error}"))
                    continue
                done = _finish(ex)
                if isinstance(done, _BatchFault):
                    faults[ex.name] = RosApiError(str(done))
                    start(_Exchange(ex.name, ex.uri, _GET_PID, ()))
                elif ex.methods:
                    results[ex.name] = done
                else:
                    results[ex.name] = reply(ex.name, done.pid)
        for sock, ex in pending.items():
            results[ex.name] = reply(ex.name, RosApiError(f"getPid on {ex.uri}: no answer "
                                                          "(timed out)"))
            sock.close()
    finally:
        sel.close()
    return results
