"""Age of messages: arrival time minus ``header.stamp``, in seconds.

Stamps come as ROS 2 / rosbags ``Time`` (``sec``, ``nanosec``), ROS 1 style (``secs``,
``nsecs``) or plain seconds; attribute objects and mappings both work. A message whose
stamp cannot be read, or whose stamp is zero (never set by the publisher), is skipped and
reported like an unreadable score (see :mod:`blackbox.observe.observers.scores`).
A negative age is kept: it means the robot's clock runs ahead, which states may judge.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from numbers import Real
from typing import Any, ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Observation
from blackbox.observe.base import OBSERVERS, ObserverKind, Quantity, Subject
from blackbox.observe.fieldpath import compile_field_access, describe_value
from blackbox.observe.observers.entry import PublisherGroup, read_filtered_group
from blackbox.observe.observers.quantity import (
    FilteredQuantity,
    JudgedObserver,
    SampleProblems,
    number,
)
from blackbox.observe.states import StateSpec

_STAMP_FIELDS = (("sec", "nanosec"), ("secs", "nsecs"))
_read_stamp = compile_field_access("header.stamp")


def _part(stamp: Any, name: str) -> Any:
    if isinstance(stamp, Mapping):
        return stamp.get(name)
    return getattr(stamp, name, None)


def stamp_seconds(stamp: Any) -> float:
    """Seconds of a message time stamp in any of the accepted shapes."""
    if not isinstance(stamp, bool) and isinstance(stamp, Real):
        return float(stamp)
    for sec_name, nsec_name in _STAMP_FIELDS:
        sec, nsec = _part(stamp, sec_name), _part(stamp, nsec_name)
        if isinstance(sec, Real) and isinstance(nsec, Real):
            return float(sec) + float(nsec) * 1e-9
    raise ValueError(f"header.stamp is {describe_value(stamp)}, not a time "
                     "(sec/nanosec, secs/nsecs or seconds)")


class TimestampObserver(JudgedObserver):
    """Receive time minus header stamp for one publisher group on one topic."""

    type_name: ClassVar[str] = "timestamp"

    def __init__(self, group: PublisherGroup, age: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        super().__init__(group.resource, (age,), states, every)
        self.group = group
        self.age = age
        self._group = group.members
        self._problems = SampleProblems()

    def interest(self) -> Interest:
        return Interest(decoded=frozenset({self.group.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        if self._group and msg.publisher not in self._group:
            return
        value = self._problems.value_of(msg)
        if value is None:
            return
        try:
            stamp = stamp_seconds(_read_stamp(value))
        except ValueError as exc:
            self._problems.add(str(exc))
            return
        if stamp == 0.0:
            self._problems.add("header.stamp is zero (not set by the publisher)")
            return
        self.age.update(msg.time - stamp)

    def evaluate(self, now: float) -> list[Observation]:
        summary = self.age.summary()
        skipped = self._problems.report(now, self.type_name, self.resource,
                                        None if summary is None else {"age": summary.value})
        if skipped is not None:
            return [skipped]
        if summary is None:
            return [self.unavailable(now, "waiting for first message")]
        return [self.judged(now, {"age": summary}, f"age {number(summary.value)} s")]

    def subject(self) -> str:
        return self.group.describe()


def timestamp_from_config(node: ConfigNode) -> TimestampObserver:
    group, judged = read_filtered_group(node, "age")
    return TimestampObserver(group, judged.quantities["age"], judged.states, judged.every)


def timestamp_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    out.filtered_per_publisher_group(group, "timestamp", {"age": "age"})


OBSERVERS.add("timestamp", ObserverKind(
    "timestamp", timestamp_from_config, Subject.TOPIC, (Quantity("age", "s"),),
    tug=timestamp_from_tug),
    example={"type": "timestamp", "topic": "/camera/image",
             "filter": {"type": "mean", "window_size": 3},
             "states": [{"number": 1, "name": "fresh",
                         "age": {"value": {"type": "less_than", "less_than": 0.2}}}]})
