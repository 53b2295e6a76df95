"""A number a topic publishes (a score, a sensor value), read by field path and filtered.

Messages are decoded lazily: only this observer's ``msg.value`` access decodes them.

A message whose field cannot be read (the path does not resolve, the value is not a
number, or it is NaN or infinite) is skipped: it never reaches the filter. If any message
since the previous evaluation was skipped, the observation is ``GENERAL_ERROR`` naming the
reason: the publisher sends values the model cannot read, which someone must look at
whether the robot or the model is wrong. A source that cannot decode the topic at all
makes the observation ``NOT_AVAILABLE``: that is the black box's limit, not a robot fault.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Observation, Resource
from blackbox.observe.base import OBSERVERS, Mode, ObserverKind, Quantity, Subject
from blackbox.observe.fieldpath import compile_field_path
from blackbox.observe.observers.entry import COMMON_KEYS, read_judged, read_name
from blackbox.observe.observers.quantity import (
    FilteredQuantity,
    JudgedObserver,
    SampleProblems,
    number,
)
from blackbox.observe.states import StateSpec

DEFAULT_FIELD = "data"


class ScoresObserver(JudgedObserver):
    """A numeric field of every message on one topic."""

    type_name: ClassVar[str] = "scores"

    def __init__(self, topic: str, field: str, score: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        super().__init__(Resource(topic=topic), (score,), states, every)
        self.topic = topic
        self.field = field
        self.score = score
        self._read: Callable[[Any], float] = compile_field_path(field)
        self._problems = SampleProblems()

    def interest(self) -> Interest:
        return Interest(decoded=frozenset({self.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        value = self._problems.value_of(msg)
        if value is None:
            return
        try:
            x = self._read(value)
        except ValueError as exc:
            self._problems.add(str(exc))
            return
        if not math.isfinite(x):
            self._problems.add(f"{self.field} is {x}, not a finite number")
            return
        self.score.update(x)

    def evaluate(self, now: float) -> list[Observation]:
        summary = self.score.summary()
        skipped = self._problems.report(now, self.type_name, self.resource,
                                        None if summary is None else {"score": summary.value})
        if skipped is not None:
            return [skipped]
        if summary is None:
            return [self.unavailable(now, "waiting for first message")]
        return [self.judged(now, {"score": summary}, f"score {number(summary.value)}")]

    def subject(self) -> str:
        return f"{self.topic} field {self.field}"


def scores_from_config(node: ConfigNode) -> ScoresObserver:
    node.check_keys((*COMMON_KEYS, "topic", "field", "filter", "states"))
    field_node = node.get("field")
    field = DEFAULT_FIELD if field_node is None else field_node.str()
    try:
        compile_field_path(field)
    except ValueError as exc:
        raise (field_node or node).error(str(exc)) from None
    topic = read_name(node, "topic")
    judged = read_judged(node, {"filter": "score"})
    return ScoresObserver(topic, field, judged.quantities["score"], judged.states, judged.every)


def scores_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    group.check_keys(["type", "main_loop_rate", "topics", *tug.IGNORED])
    every = tug.every(group)
    for topic in group["topics"].list():
        topic.check_keys(["name", "filter", "states"])
        out.entries.append(tug.entry(
            "scores", topic, topic=topic["name"], every=every,
            filter=tug.filter_entry(tug.child(topic, "filter")),
            states=tug.states(tug.child(topic, "states"), {"score": "score"})))


OBSERVERS.add("scores", ObserverKind(
    "scores", scores_from_config, Subject.TOPIC, (Quantity("score"),), judges=Mode.RIGHT,
    tug=scores_from_tug),
    example={"type": "scores", "topic": "/signal", "field": "data",
             "filter": {"type": "median", "window_size": 5},
             "states": [{"number": 1, "name": "level",
                         "score": {"value": {"type": "in_between", "lower_bound": 0.0,
                                             "upper_bound": 2.0}}}]})
