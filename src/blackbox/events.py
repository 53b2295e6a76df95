"""The events every stage shares: what a source reports and what observers ask of it.

A source turns a robot (simulated, ROS 1, bag replay, ...) into a time-ordered stream of
these events; observers only ever see them, never the middleware; the recorder and the
sinks keep them. They sit in their own module, below every stage, so that observe,
diagnose, record and transport depend on the events and not on the sources that make them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from blackbox.model import BlackBoxEvent

__all__ = [
    "ArrivalBatch",
    "Event",
    "GraphSnapshot",
    "Interest",
    "MeasurementGap",
    "MessageArrival",
    "NetworkSample",
    "NodeInfo",
    "ResourceSample",
    "TopicInfo",
    "TopicSchema",
    "merge_interests",
]


@dataclass(frozen=True, slots=True)
class NodeInfo:
    """A node as the black box sees it. ``alive`` comes from the node itself, not a registry."""

    name: str
    alive: bool
    pid: int | None = None
    host: str | None = None


@dataclass(frozen=True, slots=True)
class TopicInfo:
    name: str
    type: str = ""
    publishers: tuple[str, ...] = ()
    subscribers: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class GraphSnapshot:
    """Nodes and topics at one moment."""

    time: float
    nodes: Mapping[str, NodeInfo] = field(default_factory=dict)
    topics: Mapping[str, TopicInfo] = field(default_factory=dict)


class MessageArrival:
    """One message seen on a topic from one publisher.

    ``value`` decodes lazily and at most once, so topics observed only for timing
    never pay for decoding. ``raw`` returns the serialized bytes, also lazily. ``memo``
    holds what observers derive from the decoded message (a field's number, its sample
    time), so the ten observers that read one field read it once.
    """

    __slots__ = ("_decode", "_memo", "_raw", "_value", "publisher", "size", "time", "topic")

    _MISSING: Any = object()

    def __init__(
        self,
        time: float,
        topic: str,
        publisher: str,
        size: int,
        decode: Callable[[], Any] | None = None,
        raw: Callable[[], bytes] | None = None,
        value: Any = _MISSING,
    ) -> None:
        self.time = time
        self.topic = topic
        self.publisher = publisher
        self.size = size
        self._decode = decode
        self._raw = raw
        self._value = value
        self._memo: dict[Any, Any] | None = None

    @property
    def memo(self) -> dict[Any, Any]:
        """Values derived from this message, each a pure function of the message under
        its key (``("number", field path)``, ``("time", stamp path)``)."""
        memo = self._memo
        if memo is None:
            memo = self._memo = {}
        return memo

    @property
    def value(self) -> Any:
        """The decoded message (``None`` if this source cannot decode this topic)."""
        if self._value is MessageArrival._MISSING:
            self._value = self._decode() if self._decode is not None else None
        return self._value

    def raw(self) -> bytes | None:
        return self._raw() if self._raw is not None else None

    def __repr__(self) -> str:
        return (f"MessageArrival(t={self.time:.6f}, {self.topic} from {self.publisher}, "
                f"{self.size} B)")


class ArrivalBatch:
    """``count`` messages on a topic from one publisher that one receive got together.

    The compact form of ``count`` :class:`MessageArrival` s that all carry the same
    ``time`` (when the last of their bytes reached the black box) and no value: a fast
    topic observed only for its timing then costs no Python object per message. ``bytes``
    is the sum of the messages' sizes. A source hands these out only to a consumer that
    asked for them (``Interest.arrival_batches``); an observer that declares
    ``on_batch(batch)`` takes one in a single call, every other observer gets the
    equivalent arrivals one by one (:meth:`arrivals`), so both see the same counts and
    times.
    """

    __slots__ = ("bytes", "count", "publisher", "time", "topic")

    def __init__(self, time: float, topic: str, publisher: str, count: int,
                 bytes: int) -> None:
        self.time = time
        self.topic = topic
        self.publisher = publisher
        self.count = count
        self.bytes = bytes

    def arrivals(self) -> list[MessageArrival]:
        """The same messages as arrivals; sizes are the batch's mean (the exact size when
        ``count`` is 1), the last one taking the remainder."""
        n = self.count
        if n <= 0:
            return []
        size, extra = divmod(self.bytes, n)
        out = [MessageArrival(self.time, self.topic, self.publisher, size)
               for _ in range(n)]
        out[-1].size += extra
        return out

    def __repr__(self) -> str:
        return (f"ArrivalBatch(t={self.time:.6f}, {self.topic} from {self.publisher}, "
                f"{self.count} messages, {self.bytes} B)")


@dataclass(frozen=True, slots=True)
class ResourceSample:
    """CPU and memory of one node. ``None`` values come with a ``reason``."""

    time: float
    node: str
    cpu_percent: float | None
    memory_bytes: float | None
    reason: str = ""


@dataclass(frozen=True, slots=True)
class NetworkSample:
    """Cumulative byte counters of one network interface."""

    time: float
    interface: str
    rx_bytes: int
    tx_bytes: int


@dataclass(frozen=True, slots=True)
class TopicSchema:
    """How a topic's raw bytes are encoded, for writing them back out (bags, MCAP).

    ``encoding`` is ``"ros1"`` (``definition`` is the ROS 1 ``message_definition`` text and
    ``type`` like ``sensor_msgs/Image``) or ``"json"`` (``definition`` is a JSON schema).
    """

    topic: str
    type: str
    encoding: str
    definition: str
    md5sum: str = ""


@dataclass(frozen=True, slots=True)
class MeasurementGap:
    """An interval in which the black box could not measure something as it normally does.

    A rate source switching between the publishers' counters and its own subscription, a
    reconnection, a restarted master or DDS participant, or the black box itself paused,
    starved of CPU or its wall clock stepped: what arrived (or did not) in such an interval
    says nothing about the robot, so observers leave it unjudged (docs/observations.md,
    "Measurement gaps") instead of reporting a wrong rate, a time-out or a wrong value.

    ``topic`` or ``node`` names what was not measured; neither means everything (the black
    box's own pause or clock step). ``graph``: only the robot's graph was not followed (a
    ROS master restarting: publishers that appear or re-register meanwhile are not found,
    but topics already connected and node liveness are still measured), so no observer
    leaves anything unjudged; the operator is told all the same.

    ``timing_only``: the messages that did arrive are the robot's own, only their times and
    the silences between them say nothing (a publisher or the black box starved of CPU: a
    starved node sends its values late, with their own stamps). Observers judge such a gap
    like any other; learning keeps its values and drops its periods (docs/learn.md).

    A source reports a gap when it starts (``end`` is ``None``) and again, with the same
    ``start``, when measurement resumes (``end`` set); a gap known only afterwards (a
    pause) comes once with both. ``time`` is when the source says so, as for every event.
    """

    time: float
    start: float
    end: float | None
    reason: str
    topic: str | None = None
    node: str | None = None
    graph: bool = False
    timing_only: bool = False

    @property
    def everything(self) -> bool:
        return self.topic is None and self.node is None and not self.graph

    def subject(self) -> str:
        """What was not measured, in words."""
        if self.graph:
            return "the robot's graph"
        if self.topic is not None:
            return self.topic
        if self.node is not None:
            return f"node {self.node}"
        return "everything"


Event = (GraphSnapshot | MessageArrival | ArrivalBatch | ResourceSample | NetworkSample
         | MeasurementGap | BlackBoxEvent)
"""What ``Source.poll`` returns; a ``BlackBoxEvent`` reports trouble on the robot side
(a lost master, a garbage publisher) and goes to every sink. ``ArrivalBatch`` only when
the interest asked for it."""


@dataclass(frozen=True, slots=True)
class Interest:
    """What the observers need from a source.

    ``topics`` are read for arrival time and size; ``decoded`` additionally need values.
    ``max_message_bytes`` caps a single message per topic (default applies otherwise).
    ``arrival_batches``: the consumer takes :class:`ArrivalBatch` events for topics not in
    ``decoded`` (the pipeline does); a source may then hand those out instead of one
    arrival per message. Sources that do not batch ignore it.
    """

    topics: frozenset[str] = frozenset()
    decoded: frozenset[str] = frozenset()
    nodes: frozenset[str] = frozenset()
    resources: frozenset[str] = frozenset()
    network: bool = False
    max_message_bytes: Mapping[str, int] = field(default_factory=dict)
    arrival_batches: bool = False


def merge_interests(interests: Iterable[Interest]) -> Interest:
    """One interest asking for everything any of ``interests`` asks for."""
    topics: set[str] = set()
    decoded: set[str] = set()
    nodes: set[str] = set()
    resources: set[str] = set()
    network = False
    caps: dict[str, int] = {}
    for i in interests:
        topics |= i.topics
        decoded |= i.decoded
        nodes |= i.nodes
        resources |= i.resources
        network = network or i.network
        for t, cap in i.max_message_bytes.items():
            caps[t] = max(caps.get(t, 0), cap)
    return Interest(frozenset(topics | decoded), frozenset(decoded), frozenset(nodes),
                    frozenset(resources), network, caps)
