"""XML-RPC calls on a ROS 1 robot: the master's read-only API and single slave API calls.

Every call has a timeout and every failure (unreachable, timed out, malformed, an error
code) is one :class:`RosApiError`, so callers handle a robot that misbehaves in one place.
Nothing here registers anything anywhere. The graph built from these calls is in
:mod:`blackbox.sources.ros1.graph`; the frequent liveness probe, which keeps its
connections, in :mod:`blackbox.sources.ros1.slave_probe`.
"""

from __future__ import annotations

import http.client
import socket
import xmlrpc.client
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

from blackbox.errors import BlackBoxError

CALLER_ID = "/blackbox"
"""The caller id the black box gives in XML-RPC calls; it is never registered."""

Report = Callable[[str, str, str], None]
"""``report(kind, component, message)``: a robot-side fault the black box noticed."""


class RosApiError(BlackBoxError):
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
            raise RosApiError(f"{method} on {self.uri}: {describe_error(exc)}") from None
        except Exception as exc:  # garbage on the wire can raise anything from the parser
            raise RosApiError(f"{method} on {self.uri}: malformed reply ({describe_error(exc)})"
                              ) from None
        value = ros_value(f"{method} on {self.uri}", reply)
        if isinstance(value, RosApiError):
            raise value
        return value


def ros_value(what: str, reply: Any) -> Any:
    """The value of a ``[code, message, value]`` reply, or the :class:`RosApiError` that
    says why there is none (not raised: a batch of replies keeps the others)."""
    if not (isinstance(reply, list) and len(reply) == 3 and isinstance(reply[0], int)):
        return RosApiError(f"{what}: unexpected reply {str(reply)[:80]!r}")
    if reply[0] != 1:
        return RosApiError(f"{what}: error {reply[0]}: {reply[1]}")
    return reply[2]


def describe_error(exc: BaseException) -> str:
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


def probe_pid(uri: str, timeout: float) -> int:
    """The pid a node reports through its own slave API (raises :class:`RosApiError`)."""
    pid = RosApi(uri, timeout).call("getPid", CALLER_ID)
    if not isinstance(pid, int):
        raise RosApiError(f"getPid on {uri}: not a pid: {pid!r}")
    return pid
