"""A throw-away observer type in one file: messages per evaluation on a topic.

Everything the other stages need comes with its registration: the quantity ``burst`` and
its unit, the failure mode it judges (the values, not the rate), a fixed threshold and a
tug_observers form (group type ``burst`` with ``topics: [{name, states}]``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Observation, Resource
from blackbox.observe.base import (
    OBSERVERS,
    FixedThreshold,
    Mode,
    ObserverKind,
    Quantity,
    Subject,
    Summary,
)
from blackbox.observe.filters import NoFilter
from blackbox.observe.observers.entry import COMMON_KEYS, read_every, read_name
from blackbox.observe.observers.quantity import FilteredQuantity, JudgedObserver
from blackbox.observe.states import StateSpec, parse_states


class BurstObserver(JudgedObserver):
    type_name: ClassVar[str] = "burst"

    def __init__(self, topic: str, states: Sequence[StateSpec], every: float) -> None:
        super().__init__(Resource(topic=topic), (FilteredQuantity("burst", NoFilter()),),
                         states, every)
        self.topic = topic
        self._count = 0

    def interest(self) -> Interest:
        return Interest(topics=frozenset({self.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        self._count += 1

    def evaluate(self, now: float) -> list[Observation]:
        count, self._count = self._count, 0
        summary = Summary(float(count), None, 1)
        return [self.judged(now, {"burst": summary}, f"{count} messages")]


def burst_from_config(node: ConfigNode) -> BurstObserver:
    node.check_keys((*COMMON_KEYS, "topic", "states"))
    return BurstObserver(read_name(node, "topic"), parse_states(node.get("states"), ("burst",)),
                         read_every(node))


def burst_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    group.check_keys(["type", "main_loop_rate", "topics"])
    every = tug.every(group)
    for topic in group["topics"].list():
        topic.check_keys(["name", "states"])
        out.entries.append(tug.entry(
            "burst", topic, topic=topic["name"], every=every,
            states=tug.states(tug.child(topic, "states"), {"messages": "burst"})))


OBSERVERS.add("burst", ObserverKind(
    "burst", burst_from_config, Subject.TOPIC, (Quantity("burst", "msg"),), judges=Mode.RIGHT,
    thresholds=(FixedThreshold("burst", "min", 1.0),), tug=burst_from_tug),
    example={"type": "burst", "topic": "/toy",
             "states": [{"number": 1, "name": "steady",
                         "burst": {"value": {"type": "greater_than", "greater_than": 2}}}]})
