"""Watching a healthy robot through the public Source interface and keeping what it did.

A source is told at ``start`` which topics to read, and a new robot's topics are not known
in advance, so learning opens the source twice: a short *discovery* (graph only, until the
first snapshot that names topics) and then the *learning run* with every topic, node and
resource of that graph in its interest. Anything the robot does during the run is recorded
per topic (arrival times per publisher, numeric fields) and per node (liveness, CPU,
memory); nothing is judged yet (``blackbox.learn.model`` does that).

A node seen dead during the run splits its topics' arrival times: an interval that spans a
time the publisher was dead is not a period of the healthy robot and is not recorded. A
measurement gap (``MeasurementGap``: the black box could not measure a topic, or anything,
for a while) is skipped the same way: values stamped inside it are not kept and an
interval between arrivals that spans it is not a period. A timing-only gap (a publisher or
the black box starved of CPU) drops the periods alone: the values a starved node sent late
are its own, and a loaded computer that learns must not lose most of them (at load 15-25
on two cores the starvation gaps had kept 6,714 IMU messages of two minutes out of
learning, and relations went unlearned).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from blackbox.events import (
    GraphSnapshot,
    Interest,
    MeasurementGap,
    MessageArrival,
    ResourceSample,
)
from blackbox.learn.fields import Discovery, FieldInfo, discover
from blackbox.learn.timed import MAX_ELEMENTS, TimedSeries
from blackbox.model import BlackBoxEvent
from blackbox.observe.fieldpath import compile_field_access
from blackbox.observe.observers.fields import summarise
from blackbox.observe.observers.timestamp import stamp_seconds
from blackbox.observe.signals import sample_time
from blackbox.sources.base import Source

ARRAY_SUMMARIES = ("mean", "min", "max", "finite")
MAX_SAMPLES = 200_000
"""Per series; a longer run keeps every second sample beyond this (memory stays bounded)."""


class Series:
    """Samples of one quantity in arrival order, bounded in memory."""

    __slots__ = ("_skip", "_stride", "values")

    def __init__(self) -> None:
        self.values: list[float] = []
        self._stride = 1
        self._skip = 0

    def add(self, x: float) -> None:
        if self._skip:
            self._skip -= 1
            return
        self.values.append(x)
        self._skip = self._stride - 1
        if len(self.values) >= MAX_SAMPLES:
            self.values = self.values[::2]
            self._stride *= 2

    def array(self) -> np.ndarray:
        return np.asarray(self.values, dtype=np.float64)

    def __len__(self) -> int:
        return len(self.values)


@dataclass
class FieldRecord:
    info: FieldInfo
    access: Callable[[Any], Any]
    series: dict[str, Series] = field(default_factory=dict)
    """``value`` for scalars; ``mean``, ``min``, ``max``, ``finite`` for arrays; ``age``
    for the stamp."""
    timed: dict[str, TimedSeries] = field(default_factory=dict)
    """Time-stamped samples for relations: ``value`` for a scalar, ``[i]`` per element of a
    short array (``blackbox.learn.timed``)."""
    element_low: float = math.inf
    element_high: float = -math.inf
    problems: int = 0
    last_problem: str = ""


@dataclass
class TopicRecord:
    name: str
    type: str
    publishers: set[str] = field(default_factory=set)
    subscribers: set[str] = field(default_factory=set)
    last_arrival: dict[str, float] = field(default_factory=dict)
    periods: dict[str, Series] = field(default_factory=dict)
    messages: dict[str, int] = field(default_factory=dict)
    first: float | None = None
    last: float | None = None
    discovery: Discovery | None = None
    fields: list[FieldRecord] = field(default_factory=list)
    undecodable: int = 0
    decode_reason: str = ""
    split_gaps: int = 0
    unmeasured: int = 0
    """Messages stamped inside a measurement gap (not learned from)."""
    stamp_path: str | None = None
    """The header stamp that times this topic's samples for relations (``sample_time``)."""
    stamp_field: FieldRecord | None = None
    """The field at ``stamp_path``, found once when the topic's fields are discovered."""

    @property
    def total(self) -> int:
        return sum(self.messages.values())


@dataclass
class NodeRecord:
    name: str
    alive_seen: bool = False
    dead_since: float | None = None
    dead_spans: list[tuple[float, float | None]] = field(default_factory=list)
    cpu: Series = field(default_factory=Series)
    memory: Series = field(default_factory=Series)
    missing_reason: str = ""
    missing: int = 0
    pid: int | None = None
    host: str | None = None

    def dead_between(self, start: float, end: float) -> bool:
        return any(a <= end and (b is None or b >= start) for a, b in self.dead_spans)


@dataclass
class Recording:
    """Everything seen during the learning run."""

    source: str
    started: float
    ended: float = 0.0
    nodes: dict[str, NodeRecord] = field(default_factory=dict)
    topics: dict[str, TopicRecord] = field(default_factory=dict)
    late_topics: set[str] = field(default_factory=set)
    late_nodes: set[str] = field(default_factory=set)
    events: list[str] = field(default_factory=list)
    graphs: int = 0
    gaps: list[MeasurementGap] = field(default_factory=list)
    """Measurement gaps of topics or of everything (open ones with ``end`` None)."""

    def unmeasured(self, topic: str, start: float, end: float, *,
                   values: bool = False) -> bool:
        """Whether a measurement gap of ``topic`` (or of everything) touches
        ``[start, end]``; ``values``: only a gap in which values were not measured either
        (not a timing-only one)."""
        return any((g.topic is None or g.topic == topic) and g.start <= end
                   and (g.end is None or g.end >= start)
                   and not (values and g.timing_only) for g in self.gaps)

    @property
    def duration(self) -> float:
        return max(0.0, self.ended - self.started)


def _read_stamp(rec: FieldRecord, value: Any) -> float | str:
    """Seconds of the stamp field ``rec`` in the decoded message ``value``, or why there
    are none."""
    try:
        return stamp_seconds(rec.access(value))
    except ValueError as exc:
        return str(exc)


class Recorder:
    """Feeds source events into a :class:`Recording`."""

    def __init__(self, recording: Recording, interest: Interest) -> None:
        self.recording = recording
        self.interest = interest

    def on_graph(self, graph: GraphSnapshot) -> None:
        rec = self.recording
        rec.graphs += 1
        for name, info in graph.nodes.items():
            node = rec.nodes.get(name)
            if node is None:
                rec.late_nodes.add(name)
                node = rec.nodes[name] = NodeRecord(name)
            node.pid = info.pid if info.pid is not None else node.pid
            node.host = info.host or node.host
            if info.alive:
                node.alive_seen = True
                if node.dead_since is not None:
                    node.dead_spans[-1] = (node.dead_since, graph.time)
                    node.dead_since = None
            elif node.dead_since is None:
                node.dead_since = graph.time
                node.dead_spans.append((graph.time, None))
        for name, tinfo in graph.topics.items():
            topic = rec.topics.get(name)
            if topic is None:
                if tinfo.publishers:
                    rec.late_topics.add(name)
                continue
            topic.publishers.update(tinfo.publishers)
            topic.subscribers.update(tinfo.subscribers)
            topic.type = topic.type or tinfo.type

    def on_gap(self, gap: MeasurementGap) -> None:
        """Remember a gap of a topic or of everything (a node's or the graph's own leave
        values alone); its closing report replaces the open one."""
        if gap.graph or (gap.topic is None and gap.node is not None):
            return
        gaps = self.recording.gaps
        for i, g in enumerate(gaps):
            if g.start == gap.start and g.topic == gap.topic and g.end is None:
                gaps[i] = gap
                return
        gaps.append(gap)

    def on_message(self, msg: MessageArrival) -> None:
        topic = self.recording.topics.get(msg.topic)
        if topic is None:
            return
        t = msg.time
        gaps = self.recording
        if gaps.gaps and gaps.unmeasured(msg.topic, t, t, values=True):
            topic.unmeasured += 1  # stamped inside a measurement gap: says nothing
            topic.last_arrival.pop(msg.publisher, None)
            return
        topic.first = t if topic.first is None else topic.first
        topic.last = t
        pub = msg.publisher
        topic.messages[pub] = topic.messages.get(pub, 0) + 1
        last = topic.last_arrival.get(pub)
        topic.last_arrival[pub] = t
        if last is not None and t >= last:
            node = self.recording.nodes.get(pub)
            if (node is not None and node.dead_between(last, t)) or (
                    gaps.gaps and gaps.unmeasured(msg.topic, last, t)):
                topic.split_gaps += 1
            else:
                topic.periods.setdefault(pub, Series()).add(t - last)
        if msg.topic in self.interest.decoded:
            self._values(topic, msg)

    def _values(self, topic: TopicRecord, msg: MessageArrival) -> None:
        try:
            value = msg.value
        except Exception as exc:  # the robot's garbage, never the learner's crash
            value = None
            topic.decode_reason = f"does not decode: {exc}"
        if value is None:
            topic.undecodable += 1
            topic.decode_reason = topic.decode_reason or "the source cannot decode this topic"
            return
        if topic.discovery is None:
            topic.discovery = discover(value)
            topic.fields = [FieldRecord(f, compile_field_access(f.path))
                            for f in topic.discovery.fields]
            topic.stamp_field = next((r for r in topic.fields if r.info.kind == "stamp"),
                                     None)
            topic.stamp_path = topic.stamp_field.info.path if topic.stamp_field else None
        # The timing stamp is read once: it times this message's samples and is its own
        # ``age`` sample.
        timing = topic.stamp_field
        stamp = _read_stamp(timing, value) if timing is not None else None
        t = sample_time(msg.time, stamp) if isinstance(stamp, float) else msg.time
        for rec in topic.fields:
            if rec.info.kind == "stamp":
                seconds = stamp if rec is timing and stamp is not None else \
                    _read_stamp(rec, value)
                if isinstance(seconds, str):
                    rec.problems += 1
                    rec.last_problem = seconds
                elif seconds != 0.0:  # a stamp of zero was never set: no age
                    rec.series.setdefault("age", Series()).add(msg.time - seconds)
                continue
            try:
                raw = rec.access(value)
                if rec.info.kind == "scalar":
                    x = summarise(raw, "value", rec.info.path)
                    rec.series.setdefault("value", Series()).add(x)
                    rec.timed.setdefault("value", TimedSeries()).add(t, x)
                else:
                    self._array(rec, raw)
                    self._elements(rec, raw, t)
            except ValueError as exc:
                rec.problems += 1
                rec.last_problem = str(exc)

    @staticmethod
    def _elements(rec: FieldRecord, raw: Any, t: float) -> None:
        """Each element of a short numeric array as a signal of its own (``[i]``)."""
        if isinstance(raw, (bytes, bytearray, memoryview)):
            return
        try:
            elements = np.asarray(raw, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            return
        if elements.size > MAX_ELEMENTS:
            return
        for i, x in enumerate(elements.tolist()):
            rec.timed.setdefault(f"[{i}]", TimedSeries()).add(t, x)

    @staticmethod
    def _array(rec: FieldRecord, raw: Any) -> None:
        path = rec.info.path
        finite = summarise(raw, "finite", path)
        rec.series.setdefault("finite", Series()).add(finite)
        if finite == 0.0:
            return
        for summary in ("mean", "min", "max"):
            x = summarise(raw, summary, path)
            rec.series.setdefault(summary, Series()).add(x)
            if summary == "min":
                rec.element_low = min(rec.element_low, x)
            elif summary == "max":
                rec.element_high = max(rec.element_high, x)

    def on_resources(self, sample: ResourceSample) -> None:
        node = self.recording.nodes.get(sample.node)
        if node is None:
            return
        if sample.cpu_percent is None or sample.memory_bytes is None:
            node.missing += 1
            node.missing_reason = sample.reason or node.missing_reason
        if sample.cpu_percent is not None and math.isfinite(sample.cpu_percent):
            node.cpu.add(sample.cpu_percent)
        if sample.memory_bytes is not None and math.isfinite(sample.memory_bytes):
            node.memory.add(float(sample.memory_bytes))

    def on_event(self, event: BlackBoxEvent) -> None:
        if len(self.recording.events) < 50:
            self.recording.events.append(f"{event.kind}: {event.message}")


Progress = Callable[[float, Recording], None]
"""Called after each poll with the seconds learnt so far."""


def discover_graph(source: Source, timeout: float, step: float = 0.25,
                   troubles: list[str] | None = None) -> GraphSnapshot | None:
    """The first graph snapshot that names a topic with a publisher (or the last one seen
    when none does within ``timeout`` seconds of source time). Closes ``source``. What the
    source reported as trouble meanwhile (a master that does not answer) is appended to
    ``troubles``."""
    latest: GraphSnapshot | None = None
    try:
        source.start(Interest())
        start = source.now()
        t = start
        while True:
            for event in source.poll(t):
                if isinstance(event, GraphSnapshot):
                    latest = event
                    if any(info.publishers for info in event.topics.values()):
                        return event
                elif isinstance(event, BlackBoxEvent) and troubles is not None \
                        and len(troubles) < 5 and event.message not in troubles:
                    troubles.append(event.message)
            if t - start >= timeout:
                return latest
            t = min(t + step, start + timeout)
    finally:
        source.close()


def interest_of(graph: GraphSnapshot) -> Interest:
    topics = frozenset(name for name, info in graph.topics.items() if info.publishers)
    nodes = frozenset(graph.nodes)
    return Interest(topics=topics, decoded=topics, nodes=nodes, resources=nodes)


def record(source: Source, graph: GraphSnapshot, duration: float,
           progress: Progress | None = None, step: float = 0.5,
           stop: Callable[[], bool] | None = None) -> Recording:
    """Watch ``source`` for ``duration`` seconds with everything ``graph`` names in the
    interest. Closes ``source``."""
    interest = interest_of(graph)
    recording = Recording(source.name, 0.0)
    for name in graph.nodes:
        recording.nodes[name] = NodeRecord(name)
    for name in interest.topics:
        info = graph.topics[name]
        recording.topics[name] = TopicRecord(name, info.type, set(info.publishers),
                                             set(info.subscribers))
    recorder = Recorder(recording, interest)
    try:
        source.start(interest)
        start = source.now()
        recording.started = start
        t = start
        end = start + duration
        while t < end:
            t = min(t + step, end)
            for event in source.poll(t):
                if isinstance(event, MessageArrival):
                    recorder.on_message(event)
                elif isinstance(event, GraphSnapshot):
                    recorder.on_graph(event)
                elif isinstance(event, ResourceSample):
                    recorder.on_resources(event)
                elif isinstance(event, MeasurementGap):
                    recorder.on_gap(event)
                elif isinstance(event, BlackBoxEvent):
                    recorder.on_event(event)
            recording.ended = t
            if progress is not None:
                progress(t - start, recording)
            if stop is not None and stop():
                break
    finally:
        source.close()
    return recording
