"""Publishing rate of a topic, observed as the inter-arrival period of its messages.

The quantity is the period in seconds (``mean: 0.0667`` means 15 Hz), exactly as in the
TU Graz tool, one observer per publisher group: with ``publishers`` empty every message on
the topic counts, otherwise only messages from the listed publishers.

A topic that stops publishing produces no periods, so the filtered period alone would stay
at its last healthy value forever. At each evaluation the time since the last arrival is
therefore taken as a *provisional* period when it is longer than the filtered period: the
verdict is made on the filtered value as if the next message arrived now (which is the
shortest the real next period can be). The filter itself is not changed, so when the
message does arrive its true period is counted once. A stalled or slowed topic thus shows
at the next evaluation. A median filter ignores one outlying sample by design, so for fast
stall detection pair it with a ``timeout`` observer.
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


class HzObserver(ObserverBase):
    """Inter-arrival period of one publisher group on one topic."""

    type_name: ClassVar[str] = "hz"

    def __init__(self, topic: str, publishers: Sequence[str], period: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        self.topic = topic
        self.publishers = tuple(publishers)
        self.period = period
        self.states = tuple(states)
        self.interval = every
        self.resource = Resource(topic=topic, publishers=self.publishers)
        self._group = frozenset(self.publishers)
        self._update = period.update
        self._last: float | None = None

    def interest(self) -> Interest:
        return Interest(topics=frozenset({self.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        group = self._group
        if group and msg.publisher not in group:
            return
        t = msg.time
        last = self._last
        if last is None:
            self._last = t
        elif t >= last:
            self._update(t - last)
            self._last = t

    def evaluate(self, now: float) -> list[Observation]:
        last = self._last
        if last is None:
            return [self._unavailable(now, "waiting for first message")]
        silent = max(0.0, now - last)
        summary = self.period.summary()
        if summary is None:
            return [self._unavailable(
                now, f"waiting for a second message (one so far, {silent:.3g} s ago)",
                {"silent_for": silent})]
        note = ""
        if silent > summary.value:
            provisional = self.period.provisional_summary(silent)
            if provisional is not None:
                summary = provisional
                note = f"; no message for {silent:.3g} s (counted as a provisional period)"
        verdict = judge(self.states, {"period": summary})
        values = dict(verdict.values)
        rate = ""
        if summary.value > 0:
            values["rate_hz"] = 1.0 / summary.value
            rate = f" ({values['rate_hz']:.3g} Hz)"
        values["silent_for"] = silent
        message = f"period {number(summary.value)} s{rate} {verdict.fits}{note}"
        return [Observation(now, self.type_name, self.resource, verdict.code, verdict.states,
                            values, message)]

    def _unavailable(self, now: float, why: str,
                     values: dict[str, float] | None = None) -> Observation:
        return Observation(now, self.type_name, self.resource, Code.NOT_AVAILABLE,
                           values=values or {}, message=why)

    def describe(self) -> str:
        group = describe_publishers(self.publishers)
        return (f"hz {self.topic} [{group}]: {self.period.describe()}; "
                f"{describe_states_inline(self.states)}, every {self.interval:g} s")


@register(OBSERVERS, "hz")
def hz_from_config(node: ConfigNode) -> HzObserver:
    node.check_keys((*COMMON_KEYS, "topic", "publishers", "filter", "states"))
    return HzObserver(
        topic=read_name(node, "topic"),
        publishers=read_publishers(node),
        period=read_quantity(node, "filter", "period"),
        states=parse_states(node.get("states"), ("period",)),
        every=read_every(node),
    )
