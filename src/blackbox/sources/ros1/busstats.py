"""Topic rates from the publishers' own counters (``getBusStats``), without the payload.

A ROS 1 publisher counts the messages it wrote on each subscriber connection and answers
``getBusStats`` with them (``[topic, bytes, [[connection, bytes, messages, connected],
...]]``; ``getBusInfo`` says which caller each connection goes to). When some live node on
the robot subscribes to a topic, the publisher's count on that connection is the topic's
rate, measured on the robot: the black box needs no copy of a 14 MB/s camera stream, and a
thin link to the black box cannot make the topic look slow.

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
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from blackbox.events import MessageArrival
from blackbox.sources.ros1.callerid import is_black_box
from blackbox.sources.ros1.master import CALLER_ID, RosApi, RosApiError


@dataclass(frozen=True, slots=True)
class Connection:
    """One publisher-side connection of a topic: who receives it and what was sent."""

    id: int
    destination: str
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


def node_name(caller: str) -> str:
    """rospy lists a subscriber by its caller id; tolerate a missing leading slash."""
    return caller if caller.startswith("/") else "/" + caller


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
    """Polls ``getBusStats``/``getBusInfo`` of publishers and turns counts into arrivals."""

    def __init__(self, timeout: float = 0.5, max_workers: int = 4, *,
                 caller_id: str = CALLER_ID) -> None:
        """``caller_id``: the black box's own id on the publishers' connections (its own
        connection is never taken for a robot node's)."""
        self._timeout = timeout
        self.caller_id = caller_id
        self._pool = ThreadPoolExecutor(max_workers=max_workers,
                                        thread_name_prefix="ros1-busstats")
        self._previous: dict[tuple[str, str], _Previous] = {}

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)

    def poll(self, now: float, topics: Iterable[str],
             publishers: Mapping[str, tuple[str, ...]], uri_of: Any,
             dead: set[str]) -> list[TopicCounts]:
        """One round over ``topics``: each publisher asked once, in parallel."""
        wanted: dict[str, list[str]] = {}
        for topic in topics:
            for node in publishers.get(topic, ()):
                wanted.setdefault(node, []).append(topic)
        futures = {}
        for node in wanted:
            uri = uri_of(node)
            if uri is not None and node not in dead:
                futures[node] = self._pool.submit(self._ask, uri)
        out: list[TopicCounts] = []
        for node, fut in futures.items():
            try:
                stats, info = fut.result()
            except RosApiError:
                for topic in wanted[node]:
                    self._previous.pop((topic, node), None)
                continue
            for topic in wanted[node]:
                conns = [Connection(cid, node_name(info.get(cid, "?")), m, b, c)
                         for cid, (m, b, c) in stats.get(topic, {}).items()]
                out.append(self._count(now, topic, node, conns, dead))
        return out

    def _ask(self, uri: str) -> tuple[dict[str, dict[int, tuple[int, int, bool]]],
                                      dict[int, str]]:
        api = RosApi(uri, self._timeout)
        return (parse_bus_stats(api.call("getBusStats", CALLER_ID)),
                parse_bus_info(api.call("getBusInfo", CALLER_ID)))

    def _count(self, now: float, topic: str, node: str, conns: list[Connection],
               dead: set[str]) -> TopicCounts:
        key = (topic, node)
        prev = self._previous.get(key)
        self._previous[key] = _Previous(now, {c.id: (c.messages, c.bytes) for c in conns})
        robot = [c for c in conns if c.connected and c.destination != self.caller_id
                 and not is_black_box(c.destination) and c.destination not in dead]
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
