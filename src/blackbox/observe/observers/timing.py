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
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from blackbox.config.node import ConfigNode
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import OBSERVERS, ObserverBase, register
from blackbox.observe.observers.entry import (
    COMMON_KEYS,
    describe_publishers,
    read_bool,
    read_every,
    read_name,
    read_publishers,
    read_quantity,
)
from blackbox.observe.observers.quantity import (
    FilteredQuantity,
    describe_states_inline,
    judge,
    number,
)
from blackbox.observe.states import StateSpec, parse_states
from blackbox.sources.base import Interest, MessageArrival


class TimingObserver(ObserverBase):
    """Delay between two topics (for example a goal and its result)."""

    type_name: ClassVar[str] = "timing"

    def __init__(self, topic_a: str, publishers_a: Sequence[str], topic_b: str,
                 publishers_b: Sequence[str], delay: FilteredQuantity,
                 states: Sequence[StateSpec] = (), single_shot: bool = False,
                 every: float = 1.0) -> None:
        self.topic_a, self.topic_b = topic_a, topic_b
        self.publishers_a, self.publishers_b = tuple(publishers_a), tuple(publishers_b)
        self.delay = delay
        self.states = tuple(states)
        self.single_shot = single_shot
        self.interval = every
        # Resource.publishers names A's group; B's group shows in describe() and messages.
        self.resource = Resource(topic=topic_a, publishers=self.publishers_a, topic_b=topic_b)
        self._group_a = frozenset(self.publishers_a)
        self._group_b = frozenset(self.publishers_b)
        self._last_a: float | None = None
        self._running = False

    def interest(self) -> Interest:
        return Interest(topics=frozenset({self.topic_a, self.topic_b}))

    def on_message(self, msg: MessageArrival) -> None:
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

    def evaluate(self, now: float) -> list[Observation]:
        last_a = self._last_a
        if last_a is None:
            return [self._unavailable(now, f"waiting for a message on {self.topic_a}")]
        summary = self.delay.summary()
        waiting = max(0.0, now - last_a) if self._running else None
        if summary is None:
            return [self._unavailable(
                now, f"waiting for a message on {self.topic_b} after the one on "
                f"{self.topic_a} {max(0.0, now - last_a):.3g} s ago")]
        note = ""
        if waiting is not None and waiting > summary.value:
            provisional = self.delay.provisional_summary(waiting)
            if provisional is not None:
                summary = provisional
                note = (f"; no message on {self.topic_b} for {waiting:.3g} s since "
                        f"{self.topic_a} (counted as a provisional delay)")
        verdict = judge(self.states, {"delay": summary})
        values = dict(verdict.values)
        if waiting is not None:
            values["waiting_for"] = waiting
        return [Observation(now, self.type_name, self.resource, verdict.code, verdict.states,
                            values, f"delay {number(summary.value)} s {verdict.fits}{note}")]

    def _unavailable(self, now: float, why: str) -> Observation:
        return Observation(now, self.type_name, self.resource, Code.NOT_AVAILABLE, message=why)

    def describe(self) -> str:
        shot = ", single shot" if self.single_shot else ""
        group_a = describe_publishers(self.publishers_a)
        group_b = describe_publishers(self.publishers_b)
        return (f"timing {self.topic_a} [{group_a}] -> {self.topic_b} [{group_b}]{shot}: "
                f"{self.delay.describe()}; "
                f"{describe_states_inline(self.states)}, every {self.interval:g} s")


@register(OBSERVERS, "timing")
def timing_from_config(node: ConfigNode) -> TimingObserver:
    node.check_keys((*COMMON_KEYS, "topic_a", "publishers_a", "topic_b", "publishers_b",
                     "single_shot", "filter", "states"))
    return TimingObserver(
        topic_a=read_name(node, "topic_a"),
        publishers_a=read_publishers(node, "publishers_a"),
        topic_b=read_name(node, "topic_b"),
        publishers_b=read_publishers(node, "publishers_b"),
        delay=read_quantity(node, "filter", "delay"),
        states=parse_states(node.get("states"), ("delay",)),
        single_shot=read_bool(node, "single_shot", False),
        every=read_every(node),
    )
