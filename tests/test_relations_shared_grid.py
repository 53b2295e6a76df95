"""Relations that share a signal put it on the grid once (issue 22 item 5): a learned
robot of redundant sensors has each signal in several relations, and reading and gridding
it once per relation made relations cost more than the rest of the black box. Shared, the
verdicts are those of relations that each read the signal alone."""

from __future__ import annotations

import math
import random
from types import SimpleNamespace

from blackbox.config.node import ConfigNode
from blackbox.events import MessageArrival
from blackbox.model import Code, Observation
from blackbox.observe.base import Observer
from blackbox.observe.build import build_observer, build_observers, load_config_text
from blackbox.observe.signals import GridUser, share_cells

TOPICS = ("/a", "/b", "/c", "/d")
RATE = 50.0


def relation(a: str, b: str) -> str:
    return (f"{{type: relation, topic: {a}, topic_b: {b}, step: 0.05, block: 10, "
            f"window: 5.0, fresh: 0.1, delay: 0.1, relations: [{{name: r, target: "
            f"{{topic: {b}, field: x}}, inputs: [{{topic: {a}, field: x, lags: [0.0], "
            "gains: [1.0]}], block_noise: 0.002, cusum: {k: 0.5, h: 8}, "
            "excitation: 0.02, span: [-5, 5]}]}")


ENTRIES = [relation("/a", "/b"), relation("/b", "/c"), relation("/a", "/c"),
           relation("/c", "/d")]


def observers(shared: bool) -> list[Observer]:
    built = [build_observer(ConfigNode.parse(e)) for e in ENTRIES]
    if shared:
        share_cells(o for o in built if isinstance(o, GridUser))
    return built


def replay(watching: list[Observer], seconds: float = 60.0) -> list[list[Observation]]:
    """Four sensors of one motion, ``/c`` offset by 0.02 from 30 s to 45 s, in time order as
    the pipeline delivers them: each message to the observers whose interest names its
    topic, and every observer evaluated each second before any later message."""
    rng = random.Random(7)
    routes = {t: [o for o in watching if t in o.interest().topics | o.interest().decoded]
              for t in TOPICS}
    verdicts = []
    next_second = 1.0
    for k in range(int(seconds * RATE)):
        base = k / RATE
        for i, topic in enumerate(TOPICS):
            t = base + 0.003 * i + rng.uniform(0.0, 0.002)
            if t >= next_second:
                verdicts.append([obs for o in watching for obs in o.evaluate(next_second)])
                next_second += 1.0
            x = math.sin(0.7 * t) + rng.gauss(0.0, 0.005)
            if topic == "/c" and 30.0 <= t < 45.0:
                x += 0.02
            msg = MessageArrival(time=t, topic=topic, publisher="/p", size=8,
                                 value=SimpleNamespace(x=x))
            for o in routes[topic]:
                o.on_message(msg)
    return verdicts


def test_relations_that_share_a_signal_judge_as_if_each_read_it_alone():
    alone = replay(observers(shared=False))
    shared = replay(observers(shared=True))
    assert [[(o.code, o.message, o.values) for o in second] for second in shared] == \
        [[(o.code, o.message, o.values) for o in second] for second in alone]
    failed = {(o.resource.topic, o.resource.topic_b) for second in alone[:29] + alone[46:]
              for o in second if o.code is Code.NO_STATE_FITS}
    assert not failed, "healthy, every relation holds"
    failed = {(o.resource.topic, o.resource.topic_b) for second in alone[31:44]
              for o in second if o.code is Code.NO_STATE_FITS}
    assert failed == {("/b", "/c"), ("/a", "/c"), ("/c", "/d")}, \
        "the offset on /c fails exactly the relations that read /c"


def test_each_shared_signal_is_read_by_one_observer_only():
    built = observers(shared=True)
    readers = {t: [o for o in built if t in o.interest().decoded] for t in TOPICS}
    assert {t: len(r) for t, r in readers.items()} == {t: 1 for t in TOPICS}


def test_the_black_box_shares_the_cells_of_its_configuration():
    text = "version: 1\nobservers:\n" + "".join(f"  - {e}\n" for e in ENTRIES)
    built = build_observers(load_config_text(text, "relations.yaml"))
    assert sum(len(o.interest().decoded) for o in built) == len(TOPICS)


def test_signals_on_different_grids_are_not_shared():
    slower = relation("/a", "/b").replace("fresh: 0.1", "fresh: 0.2")
    built = [build_observer(ConfigNode.parse(e)) for e in (slower, relation("/b", "/c"))]
    assert share_cells(o for o in built if isinstance(o, GridUser)) == 0
    assert [sorted(o.interest().decoded) for o in built] == [["/a", "/b"], ["/b", "/c"]]
