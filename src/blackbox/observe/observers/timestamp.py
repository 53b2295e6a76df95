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

from blackbox.config.node import ConfigNode
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import OBSERVERS, ObserverBase, register
from blackbox.observe.fieldpath import compile_field_access, describe_value
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
    SampleProblems,
    describe_states_inline,
    judge,
    number,
)
from blackbox.observe.states import StateSpec, parse_states
from blackbox.sources.base import Interest, MessageArrival

_STAMP_FIELDS = (("sec", "nanosec"), ("secs", "nsecs"))
_read_stamp = compile_field_access("header.stamp")


def _part(stamp: Any, name: str) -> Any:
    if isinstance(stamp, Mapping):
        return stamp.get(name)
    return getattr(stamp, name, None)


def stamp_seconds(stamp: Any) -> float:
    """Seconds of a message time stamp in any of the accepted shapes."""
    if isinstance(stamp, Real) and not isinstance(stamp, bool):
        return float(stamp)
    for sec_name, nsec_name in _STAMP_FIELDS:
        sec, nsec = _part(stamp, sec_name), _part(stamp, nsec_name)
        if isinstance(sec, Real) and isinstance(nsec, Real):
            return float(sec) + float(nsec) * 1e-9
    raise ValueError(f"header.stamp is {describe_value(stamp)}, not a time "
                     "(sec/nanosec, secs/nsecs or seconds)")


class TimestampObserver(ObserverBase):
    """Receive time minus header stamp for one publisher group on one topic."""

    type_name: ClassVar[str] = "timestamp"

    def __init__(self, topic: str, publishers: Sequence[str], age: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        self.topic = topic
        self.publishers = tuple(publishers)
        self.age = age
        self.states = tuple(states)
        self.interval = every
        self.resource = Resource(topic=topic, publishers=self.publishers)
        self._group = frozenset(self.publishers)
        self._problems = SampleProblems()

    def interest(self) -> Interest:
        return Interest(decoded=frozenset({self.topic}))

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
            return [Observation(now, self.type_name, self.resource, Code.NOT_AVAILABLE,
                                message="waiting for first message")]
        verdict = judge(self.states, {"age": summary})
        return [Observation(now, self.type_name, self.resource, verdict.code, verdict.states,
                            verdict.values, f"age {number(summary.value)} s {verdict.fits}")]

    def describe(self) -> str:
        group = describe_publishers(self.publishers)
        return (f"timestamp {self.topic} [{group}]: {self.age.describe()}; "
                f"{describe_states_inline(self.states)}, every {self.interval:g} s")


@register(OBSERVERS, "timestamp")
def timestamp_from_config(node: ConfigNode) -> TimestampObserver:
    node.check_keys((*COMMON_KEYS, "topic", "publishers", "filter", "states"))
    return TimestampObserver(
        topic=read_name(node, "topic"),
        publishers=read_publishers(node),
        age=read_quantity(node, "filter", "age"),
        states=parse_states(node.get("states"), ("age",)),
        every=read_every(node),
    )
