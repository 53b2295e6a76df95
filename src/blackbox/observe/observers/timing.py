"""Delay from a message on topic A to the next message on topic B.

Each message on A (from ``publishers_a``; empty = any publisher) starts a delay; the next
message on B (from ``publishers_b``) ends it and the delay goes into the filter. Several
A messages before a B: the delay counts from the latest. ``single_shot``: only the first
B after each A counts; otherwise every B counts its delay from the latest A.
A message that belongs to both A and B (same topic, overlapping groups) first ends the
running delay, then starts a new one.

While a delay is running (an A without its B yet), an evaluation treats the time since
that A as a provisional delay when it is longer than the filtered delay, as the ``hz``
observer does with periods: a B that never comes shows without waiting for it.

Measurement gaps of either topic (or of everything): a delay running across a gap is
dropped, messages stamped inside it are not used, and while one is open the observation
is ``NOT_AVAILABLE`` ("not measured since ..."); the next A after the gap starts afresh.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MeasurementGap, MessageArrival
from blackbox.model import Observation, Resource
from blackbox.observe.base import OBSERVERS, ObserverKind, Quantity, Subject
from blackbox.observe.gaps import Unmeasured
from blackbox.observe.observers.entry import (
    COMMON_KEYS,
    PublisherGroup,
    read_bool,
    read_group,
    read_judged,
)
from blackbox.observe.observers.quantity import FilteredQuantity, JudgedObserver, number
from blackbox.observe.states import StateSpec


class TimingObserver(JudgedObserver):
    """Delay between two topics (for example a goal and its result)."""

    type_name: ClassVar[str] = "timing"

    def __init__(self, a: PublisherGroup, b: PublisherGroup, delay: FilteredQuantity,
                 states: Sequence[StateSpec] = (), single_shot: bool = False,
                 every: float = 1.0) -> None:
        # Resource.publishers names A's group; B's group shows in describe() and messages.
        super().__init__(Resource(topic=a.topic, publishers=a.publishers, topic_b=b.topic),
                         (delay,), states, every)
        self.a, self.b = a, b
        self.topic_a, self.topic_b = a.topic, b.topic
        self.delay = delay
        self.single_shot = single_shot
        self._group_a = a.members
        self._group_b = b.members
        self._last_a: float | None = None
        self._running = False
        self._gaps = Unmeasured()

    def interest(self) -> Interest:
        return Interest(topics=frozenset({self.topic_a, self.topic_b}))

    def on_message(self, msg: MessageArrival) -> None:
        if self._gaps.covers(msg.time):
            return
        topic, publisher = msg.topic, msg.publisher
        if topic == self.topic_b and (not self._group_b or publisher in self._group_b):
            last_a = self._last_a
            if last_a is not None and (self._running or not self.single_shot):
                if msg.time >= last_a:
                    self.delay.update(msg.time - last_a)
                self._running = False
        if topic == self.topic_a and (not self._group_a or publisher in self._group_a):
            self._last_a = msg.time
            self._running = True

    def on_gap(self, gap: MeasurementGap) -> None:
        if self._gaps.apply(gap):
            self._last_a = None
            self._running = False

    def evaluate(self, now: float) -> list[Observation]:
        unmeasured = self._gaps.observation(now, self.type_name, self.resource)
        if unmeasured is not None:
            return [unmeasured]
        last_a = self._last_a
        if last_a is None:
            return [self.unavailable(now, f"waiting for a message on {self.topic_a}")]
        summary = self.delay.summary()
        waiting = max(0.0, now - last_a) if self._running else None
        if summary is None:
            return [self.unavailable(
                now, f"waiting for a message on {self.topic_b} after the one on "
                f"{self.topic_a} {max(0.0, now - last_a):.3g} s ago")]
        note = ""
        if waiting is not None and waiting > summary.value:
            provisional = self.delay.provisional_summary(waiting)
            if provisional is not None:
                summary = provisional
                note = (f"; no message on {self.topic_b} for {waiting:.3g} s since "
                        f"{self.topic_a} (counted as a provisional delay)")
        extra = {"waiting_for": waiting} if waiting is not None else {}
        return [self.judged(now, {"delay": summary}, f"delay {number(summary.value)} s",
                            extra, note)]

    def subject(self) -> str:
        shot = ", single shot" if self.single_shot else ""
        return f"{self.a.describe()} -> {self.b.describe()}{shot}"


def timing_from_config(node: ConfigNode) -> TimingObserver:
    node.check_keys((*COMMON_KEYS, "topic_a", "publishers_a", "topic_b", "publishers_b",
                     "single_shot", "filter", "states"))
    a = read_group(node, "topic_a", "publishers_a")
    b = read_group(node, "topic_b", "publishers_b")
    judged = read_judged(node, {"filter": "delay"})
    return TimingObserver(a, b, judged.quantities["delay"], judged.states,
                          read_bool(node, "single_shot", False), judged.every)


def timing_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    group.check_keys(["type", "main_loop_rate", "topics", *tug.IGNORED])
    every = tug.every(group)
    for pair in group["topics"].list():
        pair.check_keys(["topicA", "calleridA", "topicB", "calleridB", "single_shot_mode",
                         "filter", "states"])
        out.entries.append(tug.entry(
            "timing", pair, topic_a=pair["topicA"],
            publishers_a=tug.publishers(tug.child(pair, "calleridA"), pair),
            topic_b=pair["topicB"],
            publishers_b=tug.publishers(tug.child(pair, "calleridB"), pair),
            single_shot=pair.get("single_shot_mode"), every=every,
            filter=tug.filter_entry(tug.child(pair, "filter")),
            states=tug.states(tug.child(pair, "states"), {"delay": "delay"})))


OBSERVERS.add("timing", ObserverKind(
    "timing", timing_from_config, Subject.TOPIC_PAIR, (Quantity("delay", "s"),),
    tug=timing_from_tug),
    example={"type": "timing", "topic_a": "/scan", "topic_b": "/map",
             "filter": {"type": "mean", "window_size": 3},
             "states": [{"number": 1, "name": "ok",
                         "delay": {"value": {"type": "less_than", "less_than": 0.1}}}]})
