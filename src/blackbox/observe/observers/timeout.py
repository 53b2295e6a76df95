"""Time-out of a topic: no message from a publisher group for longer than ``timeout``.

The observation is ``TIMEOUT`` while the time since the group's last message (or, before
any message, since the first evaluation, so a topic that never appears times out) exceeds
``timeout`` seconds, and ``GENERAL_OK`` otherwise.

``timeouts_in_a_row`` is how many whole ``timeout`` periods have passed without a message.
The TU Graz tool stopped its timer after ``max_timeouts_in_a_row`` of them; here the
observation keeps reporting ``TIMEOUT`` (the fault is still there and diagnosis must still
see it), but the count stops at the maximum and the message says the topic is considered
stopped rather than late.

Detection latency: the observer is evaluated every ``min(every, max(0.01, min(0.25,
timeout / 4)))`` seconds, so a time-out shows within ``timeout + 0.25`` s (and within
1.25 x ``timeout`` for short time-outs). To keep the observation stream at one record per
``every`` seconds, the extra evaluations return a record only when the code changes.

Measurement gaps (:class:`~blackbox.events.MeasurementGap`): no time-out verdict for a
gap. While one is open the observation is ``NOT_AVAILABLE`` ("not measured since ...");
afterwards the silence counts from the gap's end (or the first message after it), so a
topic that really stopped during the gap times out ``timeout`` seconds after measuring
resumed. Arrivals stamped inside the gap are not used.
"""

from __future__ import annotations

from typing import ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import ArrivalBatch, Interest, MeasurementGap, MessageArrival
from blackbox.model import Code, Observation
from blackbox.observe.base import (
    OBSERVERS,
    FixedThreshold,
    ObserverBase,
    ObserverKind,
    Quantity,
    Subject,
)
from blackbox.observe.gaps import Unmeasured
from blackbox.observe.observers.entry import COMMON_KEYS, PublisherGroup, read_every, read_group

DEFAULT_MAX_TIMEOUTS_IN_A_ROW = 1
_FINEST_INTERVAL = 0.01
_DETECTION_SLACK = 0.25


def detection_interval(every: float, timeout: float) -> float:
    return min(every, max(_FINEST_INTERVAL, min(_DETECTION_SLACK, timeout / 4)))


class TimeoutObserver(ObserverBase):
    """Time since the last message of one publisher group on one topic."""

    type_name: ClassVar[str] = "timeout"

    def __init__(self, group: PublisherGroup, timeout: float,
                 max_timeouts_in_a_row: int = DEFAULT_MAX_TIMEOUTS_IN_A_ROW,
                 every: float = 1.0) -> None:
        if timeout <= 0:
            raise ValueError(f"timeout must be > 0, got {timeout}")
        if max_timeouts_in_a_row < 1:
            raise ValueError(f"max_timeouts_in_a_row must be >= 1, got {max_timeouts_in_a_row}")
        self.group = group
        self.timeout = timeout
        self.max_timeouts_in_a_row = max_timeouts_in_a_row
        self.every = every
        self.interval = detection_interval(every, timeout)
        self.resource = group.resource
        self._group = group.members
        self._last: float | None = None
        self._started: float | None = None
        self._reported_code: Code | None = None
        self._reported_at = 0.0
        self._resumed: float | None = None
        self._gaps = Unmeasured()

    def interest(self) -> Interest:
        return Interest(topics=frozenset({self.group.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        group = self._group
        if group and msg.publisher not in group:
            return
        if self._gaps.covers(msg.time):
            return
        last = self._last
        if last is None or msg.time > last:
            self._last = msg.time

    def on_batch(self, batch: ArrivalBatch) -> None:
        group = self._group
        if group and batch.publisher not in group:
            return
        if self._gaps.covers(batch.time):
            return
        last = self._last
        if batch.count > 0 and (last is None or batch.time > last):
            self._last = batch.time

    def on_gap(self, gap: MeasurementGap) -> None:
        if self._gaps.apply(gap):
            self._last = None
            self._resumed = gap.end

    def evaluate(self, now: float) -> list[Observation]:
        if self._started is None:
            self._started = now
        unmeasured = self._gaps.observation(now, self.type_name, self.resource)
        if unmeasured is not None:
            if self._reported_code is Code.NOT_AVAILABLE and \
                    now - self._reported_at < self.every - 1e-9:
                return []
            self._reported_code = Code.NOT_AVAILABLE
            self._reported_at = now
            return [unmeasured]
        since = (self._last if self._last is not None
                 else self._resumed if self._resumed is not None else self._started)
        silent = max(0.0, now - since)
        timed_out = silent > self.timeout
        code = Code.TIMEOUT if timed_out else Code.GENERAL_OK
        due = (self._reported_code is None or code != self._reported_code
               or now - self._reported_at >= self.every - 1e-9)
        if not due:
            return []
        self._reported_code = code
        self._reported_at = now
        in_a_row = min(int(silent // self.timeout), self.max_timeouts_in_a_row)
        values = {"silent_for": silent, "timeouts_in_a_row": float(in_a_row)}
        return [Observation(now, self.type_name, self.resource, code, values=values,
                            message=self._message(silent, timed_out, in_a_row))]

    def _message(self, silent: float, timed_out: bool, in_a_row: int) -> str:
        limit = f"timeout {self.timeout:g} s"
        if self._last is None and self._resumed is not None:
            what = f"no message since measuring resumed {silent:.3g} s ago"
        elif self._last is None:
            what = f"no message since observation began {silent:.3g} s ago"
        elif timed_out:
            what = f"no message for {silent:.3g} s"
        else:
            return f"last message {silent:.3g} s ago ({limit})"
        if not timed_out:
            return f"{what} ({limit})"
        if in_a_row >= self.max_timeouts_in_a_row:
            return (f"{what} ({limit}, {in_a_row} in a row = max_timeouts_in_a_row: "
                    "considered stopped)")
        return f"{what} ({limit}, {in_a_row} in a row)"

    def describe(self) -> str:
        return (f"timeout {self.group.describe()}: no message for {self.timeout:g} s, "
                f"max {self.max_timeouts_in_a_row} in a row, checked every "
                f"{self.interval:g} s, reported every {self.every:g} s")


def timeout_from_config(node: ConfigNode) -> TimeoutObserver:
    node.check_keys((*COMMON_KEYS, "topic", "publishers", "timeout", "max_timeouts_in_a_row"))
    group = read_group(node)
    limit = node.get("max_timeouts_in_a_row")
    return TimeoutObserver(
        group, timeout=node["timeout"].float(min=0.0, min_exclusive=True),
        max_timeouts_in_a_row=(DEFAULT_MAX_TIMEOUTS_IN_A_ROW if limit is None
                               else limit.int(min=1)),
        every=read_every(node))


def timeout_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    out.per_publisher_group(group, "timeout", ["timeout", "max_timeouts_in_a_row"], lambda c: {
        "timeout": c.get("timeout"), "max_timeouts_in_a_row": c.get("max_timeouts_in_a_row")})


OBSERVERS.add("timeout", ObserverKind(
    "timeout", timeout_from_config, Subject.TOPIC, (Quantity("code"),),
    thresholds=(FixedThreshold("code", "min", 0.0),), tug=timeout_from_tug,
    failure_means_silent=True, logged_values=1),
    example={"type": "timeout", "topic": "/scan", "timeout": 0.5, "max_timeouts_in_a_row": 3})
