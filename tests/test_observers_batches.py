"""Arrival batches (the compact form of a fast topic's messages) give every observer exactly
what the same messages one by one give it: observers that take batches (hz, timeout) and
observers that do not (timing, which the pipeline feeds message by message) alike."""

from __future__ import annotations

import random

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigNode
from blackbox.events import ArrivalBatch, Event, MessageArrival
from blackbox.model import Observation
from blackbox.observe.base import OBSERVERS, Observer
from blackbox.pipeline import Pipeline
from blackbox.sinks import SinkBase
from blackbox.sources.memory import MemorySource

STATE = ("states: [{number: 1, name: ok, period: {value: {type: gauss, mean: 0.002, "
         "std_deviation: 0.0002}}}]")
CONFIGS = [
    "type: hz\ntopic: /fast\nfilter: {type: mean, window_size: 200}\n" + STATE,
    "type: hz\ntopic: /fast\nfilter: {type: median, window_size: 25}\n" + STATE,
    "type: hz\ntopic: /fast\npublishers: [/a]\nfilter: {type: mean, window_size: 50}\n"
    + STATE,
    "type: hz\ntopic: /slow\nfilter: {type: mean, window_size: 5}\n" + STATE,
    "type: timeout\ntopic: /fast\ntimeout: 0.05\n",
    "type: timeout\ntopic: /slow\npublishers: [/b]\ntimeout: 0.3\n",
    "type: timing\ntopic_a: /slow\ntopic_b: /fast\nfilter: {type: mean, window_size: 3}\n"
    "states: [{number: 1, name: ok, delay: {value: {type: in_between, lower_bound: 0, "
    "upper_bound: 0.1}}}]",
]


def observers() -> list[Observer]:
    return [OBSERVERS[c.split("\n")[0].removeprefix("type: ")].build(
        ConfigNode.parse(c, "t.yaml")) for c in CONFIGS]


class Kept(SinkBase):
    def __init__(self) -> None:
        self.observations: list[Observation] = []
        self.messages: list[MessageArrival] = []
        self.wants_messages = True

    def on_observations(self, now: float, observations: list[Observation]) -> None:
        self.observations.extend(observations)

    def on_message(self, msg: MessageArrival) -> None:
        self.messages.append(msg)


def stream(seed: int) -> list[ArrivalBatch]:
    """Receives of a 500 Hz topic from two publishers (bunched as a late reader gets
    them), a slow topic with a pause, times that step back (a clock raised to a floor)."""
    rng = random.Random(seed)
    batches: list[ArrivalBatch] = []
    t = 0.0
    while t < 6.0:
        t += rng.choice([0.001, 0.002, 0.002, 0.004, 0.01])
        n = rng.choice([1, 1, 1, 2, 3, 8])
        batches.append(ArrivalBatch(t, "/fast", rng.choice(["/a", "/b"]), n, 8 * n + n % 3))
        if rng.random() < 0.02:
            batches.append(ArrivalBatch(t - 0.0005, "/fast", "/a", 1, 8))
        if rng.random() < 0.03 and not 2.0 < t < 3.0:
            batches.append(ArrivalBatch(t, "/slow", "/b", rng.choice([1, 2]), 100))
    return batches


def run(events: list[Event]) -> tuple[list[Observation], Kept, int]:
    sink = Kept()
    stats = Pipeline(MemorySource(events), observers(), [sink]).run(duration=6.5)
    return sink.observations, sink, stats.messages


def test_batches_and_the_same_messages_one_by_one_give_identical_observations() -> None:
    for seed in range(3):
        batches = stream(seed)
        one_by_one: list[Event] = [a for b in batches for a in b.arrivals()]
        got, sink, messages = run(list(batches))
        want, sink_one, messages_one = run(one_by_one)
        assert messages == messages_one == sum(b.count for b in batches)
        assert [(o.time, o.observer, o.resource, o.code, o.values, o.message) for o in got] \
            == [(o.time, o.observer, o.resource, o.code, o.values, o.message) for o in want]
        assert any(o.observer == "timing" and o.code >= 0 for o in got)  # fed one by one
        assert any(o.observer == "timeout" and o.code < 0 for o in got)  # the pause
        # a sink that keeps messages gets them one by one either way, bytes preserved
        assert len(sink.messages) == len(sink_one.messages) == messages
        assert sum(m.size for m in sink.messages) == sum(b.bytes for b in batches)


def test_a_batch_expands_to_its_messages() -> None:
    batch = ArrivalBatch(2.5, "/t", "/p", 3, 31)
    arrivals = batch.arrivals()
    assert [(a.time, a.topic, a.publisher) for a in arrivals] == [(2.5, "/t", "/p")] * 3
    assert [a.size for a in arrivals] == [10, 10, 11]
    assert all(a.value is None and a.raw() is None for a in arrivals)
    assert ArrivalBatch(1.0, "/t", "/p", 0, 0).arrivals() == []
