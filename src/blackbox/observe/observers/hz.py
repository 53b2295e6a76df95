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

Measurement gaps (:class:`~blackbox.events.MeasurementGap`): while one is open the
observation is ``NOT_AVAILABLE`` ("not measured since ..."); arrivals stamped inside it
are not counted, so no period spans a gap. Measuring starts afresh at its end: the first
arrival after it starts a new period, and until then the silence counts from the gap's
end, so a topic that stopped during the gap still shows as a stall. The window keeps the
periods measured before the gap: they are true periods of the same topic, and a window
restarted from one or two periods would judge more noisily than before the gap.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import ArrivalBatch, Interest, MeasurementGap, MessageArrival
from blackbox.model import Observation
from blackbox.observe.base import OBSERVERS, ObserverKind, Quantity, Subject
from blackbox.observe.gaps import Unmeasured
from blackbox.observe.observers.entry import PublisherGroup, read_filtered_group
from blackbox.observe.observers.quantity import FilteredQuantity, JudgedObserver, number
from blackbox.observe.states import StateSpec


class HzObserver(JudgedObserver):
    """Inter-arrival period of one publisher group on one topic."""

    type_name: ClassVar[str] = "hz"

    def __init__(self, group: PublisherGroup, period: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        super().__init__(group.resource, (period,), states, every)
        self.group = group
        self.period = period
        self._group = group.members
        self._update = period.update
        self._last: float | None = None
        self._resumed: float | None = None
        self._gaps = Unmeasured()
        self._skip_until = -float("inf")
        self._in_gap = False

    def interest(self) -> Interest:
        return Interest(topics=frozenset({self.group.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        group = self._group
        if group and msg.publisher not in group:
            return
        t = msg.time
        if self._in_gap or t < self._skip_until:
            return
        last = self._last
        if last is None:
            self._last = t
        elif t >= last:
            self._update(t - last)
            self._last = t

    def on_batch(self, batch: ArrivalBatch) -> None:
        """``batch.count`` arrivals at one time in one call: the first ends the running
        period, the others are periods of zero, exactly as they would be one by one."""
        group = self._group
        if group and batch.publisher not in group:
            return
        t = batch.time
        if self._in_gap or t < self._skip_until:
            return
        last = self._last
        update = self._update
        if last is None:
            self._last = t
        elif t >= last:
            update(t - last)
            self._last = t
        else:
            return
        for _ in range(batch.count - 1):
            update(0.0)

    def on_gap(self, gap: MeasurementGap) -> None:
        if self._gaps.apply(gap):
            self._last = None
            self._resumed = gap.end
        self._in_gap = self._gaps.open
        self._skip_until = self._gaps.ended

    def evaluate(self, now: float) -> list[Observation]:
        unmeasured = self._gaps.observation(now, self.type_name, self.resource)
        if unmeasured is not None:
            return [unmeasured]
        last = self._last
        summary = self.period.summary()
        if last is None and (self._resumed is None or summary is None):
            return [self.unavailable(now, "waiting for first message")]
        since = last if last is not None else self._resumed
        assert since is not None
        silent = max(0.0, now - since)
        if summary is None:
            return [self.unavailable(
                now, f"waiting for a second message (one so far, {silent:.3g} s ago)",
                {"silent_for": silent})]
        note = ""
        if last is None:
            note = f"; measuring again since a gap ended {silent:.3g} s ago"
        if silent > summary.value:
            provisional = self.period.provisional_summary(silent)
            if provisional is not None:
                summary = provisional
                note += f"; no message for {silent:.3g} s (counted as a provisional period)"
        extra = {"rate_hz": 1.0 / summary.value} if summary.value > 0 else {}
        rate = f" ({extra['rate_hz']:.3g} Hz)" if extra else ""
        return [self.judged(now, {"period": summary}, f"period {number(summary.value)} s{rate}",
                            {**extra, "silent_for": silent}, note)]

    def subject(self) -> str:
        return self.group.describe()


def hz_from_config(node: ConfigNode) -> HzObserver:
    group, judged = read_filtered_group(node, "period")
    return HzObserver(group, judged.quantities["period"], judged.states, judged.every)


def hz_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    out.filtered_per_publisher_group(group, "hz", {"frequenzy": "period", "frequenz": "period"})


OBSERVERS.add("hz", ObserverKind(
    "hz", hz_from_config, Subject.TOPIC, (Quantity("period", "s"),), tug=hz_from_tug),
    example={"type": "hz", "topic": "/scan", "filter": {"type": "mean", "window_size": 5},
             "states": [{"number": 1, "name": "ok", "period": {"value": {
                 "type": "gauss", "mean": 0.1, "std_deviation": 0.02}}}]})
