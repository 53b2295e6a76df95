"""Topic rates from the publishers' own counters (``getBusStats``), without the payload.

A ROS 1 publisher counts the messages it wrote on each subscriber connection and answers
``getBusStats`` with them (``[topic, bytes, [[connection, bytes, messages, connected],
...]]``; ``getBusInfo`` says which caller each connection goes to). When some live node on
the robot subscribes to a topic, the publisher's count on that connection is the topic's
rate, measured on the robot: the black box needs no copy of a 14 MB/s camera stream, and a
thin link to the black box cannot make the topic look slow.

The calls ride on the liveness probe: each round the black box already asks every node
for its pid, and ``getBusStats`` goes in the same ``system.multicall`` request.
``getBusInfo`` (which caller each connection id belongs to) is asked only when a count
names a connection the black box has not seen in that process (keyed by pid), so a steady
robot costs one request per publisher per round, not three.

Each round, the count increase on the busiest live on-robot connection since the previous
round becomes that many :class:`MessageArrival` s spread evenly over a span as long as that
interval, starting now (size: serialized bytes per message, averaged over the round; no
value). So rate and time-out observers work unchanged and events stay in time order; the
price is one round (``graph_period``, 0.45 s) of extra latency on counted topics. Topics
whose values are observed are still subscribed; for those the counters tell when the black
box receives fewer messages than an on-robot subscriber, i.e. when it cannot keep up with
the topic over its link.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from blackbox.events import MessageArrival
from blackbox.sources.ros1.callerid import is_black_box
from blackbox.sources.ros1.master import CALLER_ID, RosApiError
from blackbox.sources.ros1.slave_probe import NodeReply


@dataclass(frozen=True, slots=True)
class Connection:
    """One publisher-side connection of a topic: who receives it and what was sent.

    ``destination`` is ``None`` while the black box does not yet know it (a connection
    opened since the last ``getBusInfo``); such a connection counts for nobody."""

    id: int
    destination: str | None
    messages: int
    bytes: int
    connected: bool


def parse_bus_stats(stats: Any) -> dict[str, dict[int, tuple[int, int, bool]]]:
    """``getBusStats`` publications as topic -> connection id -> (messages, bytes, connected).

    Malformed entries are skipped (a C++ node answers in a slightly different shape)."""
    out: dict[str, dict[int, tuple[int, int, bool]]] = {}
    pubs = stats[0] if isinstance(stats, list | tuple) and stats else []
    for entry in pubs if isinstance(pubs, list | tuple) else ():
        if not (isinstance(entry, list | tuple) and len(entry) == 3
                and isinstance(entry[0], str) and isinstance(entry[2], list | tuple)):
            continue
        conns: dict[int, tuple[int, int, bool]] = {}
        for c in entry[2]:
            if (isinstance(c, list | tuple) and len(c) >= 4 and isinstance(c[0], int)
                    and isinstance(c[1], int) and isinstance(c[2], int)):
                conns[c[0]] = (c[2], c[1], bool(c[3]))
        out[entry[0]] = conns
    return out


def parse_bus_info(info: Any) -> dict[int, str]:
    """``getBusInfo``: connection id -> destination caller id, outgoing connections only."""
    out: dict[int, str] = {}
    for c in info if isinstance(info, list | tuple) else ():
        if (isinstance(c, list | tuple) and len(c) >= 5 and isinstance(c[0], int)
                and isinstance(c[1], str) and c[2] in ("o", "b")):
            out[c[0]] = c[1]
    return out


def _destination(caller: str | None) -> str | None:
    """rospy lists a subscriber by its caller id; tolerate a missing leading slash."""
    if caller is None:
        return None
    return caller if caller.startswith("/") else "/" + caller


STATS = ("getBusStats",)
STATS_AND_INFO = ("getBusStats", "getBusInfo")


@dataclass(slots=True)
class _Previous:
    time: float
    counts: dict[int, tuple[int, int]] = field(default_factory=dict)


@dataclass(slots=True)
class TopicCounts:
    """What one round learnt about one (topic, publisher)."""

    topic: str
    publisher: str
    on_robot: bool
    """Some live node on the robot has a connected subscription."""
    arrivals: list[MessageArrival]
    robot_sent: int | None
    """Messages sent on the busiest live on-robot connection since the last round."""
    own_sent: int | None
    """Messages sent on the black box's own connection since the last round."""


class BusStatsRates:
    """Turns the publishers' counters, read each round, into arrivals.

    Pure bookkeeping: :meth:`calls` says what to ask each node this round, the graph
    poller asks it along with its liveness probe, and :meth:`count` reads the answers.
    """

    def __init__(self, *, caller_id: str = CALLER_ID) -> None:
        """``caller_id``: the black box's own id on the publishers' connections (its own
        connection is never taken for a robot node's)."""
        self.caller_id = caller_id
        self._previous: dict[tuple[str, str], _Previous] = {}
        self._info: dict[str, tuple[int, dict[int, str]]] = {}
        self._stale: set[str] = set()
        self.unavailable: dict[str, str] = {}
        """Publishers whose counters the last round could not read, and why."""

    def calls(self, topics: Iterable[str], publishers: Mapping[str, tuple[str, ...]],
              dead: set[str]) -> dict[str, tuple[str, ...]]:
        """The slave API methods to ask each live publisher of ``topics`` this round."""
        nodes = {n for t in topics for n in publishers.get(t, ()) if n not in dead}
        return {n: STATS if n in self._info and n not in self._stale else STATS_AND_INFO
                for n in sorted(nodes)}

    def count(self, now: float, topics: Iterable[str],
              publishers: Mapping[str, tuple[str, ...]], replies: Mapping[str, NodeReply],
              dead: set[str]) -> list[TopicCounts]:
        """One round's counts for ``topics`` from the nodes' ``replies``.

        A publisher that gave no counts this round (dead, no ``system.multicall``, an
        error) has its history dropped, so its next counts start afresh."""
        wanted: dict[str, list[str]] = {}
        for topic in topics:
            for node in publishers.get(topic, ()):
                wanted.setdefault(node, []).append(topic)
        out: list[TopicCounts] = []
        self.unavailable = {}
        for node, node_topics in wanted.items():
            reply = replies.get(node)
            stats_value = reply.extra.get("getBusStats") if reply is not None else None
            if reply is None or stats_value is None or isinstance(stats_value, RosApiError):
                self.unavailable[node] = (str(stats_value) if stats_value is not None
                                          else "not asked this round")
                for topic in node_topics:
                    self._previous.pop((topic, node), None)
                continue
            stats = parse_bus_stats(stats_value)
            info = self._destinations(node, reply, stats)
            for topic in node_topics:
                conns = [Connection(cid, _destination(info.get(cid)), m, b, c)
                         for cid, (m, b, c) in stats.get(topic, {}).items()]
                out.append(self._count(now, topic, node, conns, dead))
        return out

    def _destinations(self, node: str, reply: NodeReply,
                      stats: dict[str, dict[int, tuple[int, int, bool]]]) -> dict[int, str]:
        """Connection id -> caller id for ``node``'s current process, refreshed when the
        process changed or a count names a connection not seen before."""
        pid = reply.pid if isinstance(reply.pid, int) else -1
        fresh = reply.extra.get("getBusInfo")
        if fresh is not None and not isinstance(fresh, RosApiError):
            self._info[node] = (pid, parse_bus_info(fresh))
        known_pid, info = self._info.get(node, (None, {}))
        if known_pid != pid:
            info = {}
        ids = {cid for conns in stats.values() for cid in conns}
        if ids <= info.keys():
            self._stale.discard(node)
        else:
            self._stale.add(node)
        return info

    def _count(self, now: float, topic: str, node: str, conns: list[Connection],
               dead: set[str]) -> TopicCounts:
        key = (topic, node)
        prev = self._previous.get(key)
        self._previous[key] = _Previous(now, {c.id: (c.messages, c.bytes) for c in conns})
        robot = [c for c in conns if c.connected and c.destination is not None
                 and c.destination != self.caller_id and not is_black_box(c.destination)
                 and c.destination not in dead]
        own = [c for c in conns if c.destination == self.caller_id]
        result = TopicCounts(topic, node, bool(robot), [], None, None)
        if prev is None:
            return result
        deltas = [(c.messages - prev.counts[c.id][0], c.bytes - prev.counts[c.id][1])
                  for c in robot if c.id in prev.counts]
        own_deltas = [c.messages - prev.counts[c.id][0] for c in own if c.id in prev.counts]
        if own_deltas:
            result.own_sent = max(own_deltas)
        if not deltas:
            return result
        n, size = max(deltas)
        result.robot_sent = n
        if n > 0:
            span = now - prev.time
            per = max(size // n - 4, 0)  # the counters include each 4-byte length prefix
            result.arrivals = [MessageArrival(now + span * (k + 1) / n, topic, node, per)
                               for k in range(n)]
        return result
