"""Signals that climb on their own (issue 22 item 7): learning relates them on their
changes, not their level, unless the level is the relation.

A wheel angle climbs as the robot drives; its level correlates with anything else that
climbs or falls over the learning run (a discharging battery, the heading) whatever the
physics, and a relation fitted on it runs away with it once the robot has driven farther
than learning saw. Its changes (the wheel's speed) are what relate to a motor current.
Two encoders of one wheel are the exception: their levels are the same quantity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from blackbox.events import GraphSnapshot, MessageArrival, NodeInfo, TopicInfo
from blackbox.learn import learn_from, render_config
from blackbox.learn.relations import LEVEL_IDENTITY, R2_MIN, _climbing_choice
from blackbox.model import Code
from blackbox.observe.build import build_observer, load_config_text
from blackbox.sources.memory import MemorySource

TOPICS = {"/wheel": "/base", "/encoder": "/encoder_driver", "/motor": "/motor_monitor"}
RATE = 20.0


@dataclass(frozen=True)
class Angle:
    angle: float


@dataclass(frozen=True)
class Current:
    current: float


def speed(t: float) -> float:
    """Always forward, never steady."""
    return 1.0 + 0.7 * math.sin(2 * math.pi * t / 9.0) + 0.25 * math.sin(2 * math.pi * t / 4.1)


def graph(t: float) -> GraphSnapshot:
    nodes = {n: NodeInfo(n, True, 100 + i) for i, n in enumerate(TOPICS.values())}
    topics = {name: TopicInfo(name, "std_msgs/Float64", (node,), ())
              for name, node in TOPICS.items()}
    return GraphSnapshot(t, nodes, topics)


def robot(start: float, seconds: float, seed: int = 0) -> list:
    """A wheel angle (the integral of the speed), a second encoder of the same wheel and a
    motor current that follows the speed, from ``start`` (the angle already at
    ``speed`` integrated from 0)."""
    rng = np.random.default_rng(seed)
    events: list = [graph(start + float(k)) for k in range(int(seconds) + 1)]
    dt = 1.0 / RATE
    angle = 0.0
    t = 0.0
    while t < start:  # the distance driven before: hours later, far past what was learned
        angle += speed(t) * dt
        t += dt
    k = 0
    while k * dt < seconds:
        t = start + k * dt
        angle += speed(t) * dt
        events.append(MessageArrival(t + 0.002, "/wheel", "/base", 8,
                                     value=Angle(angle + rng.normal(0, 0.002))))
        events.append(MessageArrival(t + 0.004, "/encoder", "/encoder_driver", 8,
                                     value=Angle(angle + rng.normal(0, 0.002))))
        events.append(MessageArrival(t + 0.007, "/motor", "/motor_monitor", 8,
                                     value=Current(2.0 + 3.0 * speed(t)
                                                   + rng.normal(0, 0.05))))
        k += 1
    return sorted(events, key=lambda e: e.time)


@pytest.fixture(scope="module")
def learned_text() -> str:
    learned = learn_from(lambda: MemorySource(robot(0.0, 120.0)), 120.0)
    return render_config(learned, "r", "r.model.yaml", "now")


def relations(text: str) -> dict[str, dict]:
    config = load_config_text(text, "r.yaml")
    out = {}
    for entry in config.observers:
        data = entry.to_python()
        if data["type"] == "relation":
            for r in data["relations"]:
                out[f"{r['target']['topic']} <- "
                    + ",".join(i["topic"] for i in r["inputs"])] = r
    return out


def test_a_current_is_related_to_the_changes_of_a_climbing_wheel_angle(learned_text: str):
    rels = relations(learned_text)
    current = rels.get("/motor <- /wheel") or rels.get("/motor <- /encoder")
    assert current is not None, sorted(rels)
    gains = current["inputs"][0]["gains"]
    assert abs(sum(gains)) < 1e-6 * max(abs(g) for g in gains), gains
    assert "taps summing to zero" in learned_text


def test_two_encoders_of_one_wheel_are_related_on_their_level(learned_text: str):
    rels = relations(learned_text)
    same = rels.get("/encoder <- /wheel") or rels.get("/wheel <- /encoder")
    assert same is not None, sorted(rels)
    assert sum(same["inputs"][0]["gains"]) == pytest.approx(1.0, abs=0.05)


def test_an_hour_later_the_healthy_robot_raises_nothing(learned_text: str):
    """The wheel has turned thousands of radians more than learning saw."""
    config = load_config_text(learned_text, "r.yaml")
    observers = [build_observer(e) for e in config.observers
                 if e.to_python()["type"] == "relation"]
    verdicts = []
    evaluate_at = 3601.0
    for event in robot(3600.0, 60.0, seed=5):
        if not isinstance(event, MessageArrival):
            continue
        while event.time >= evaluate_at:
            verdicts += [o for obs in observers for o in obs.evaluate(evaluate_at)]
            evaluate_at += 1.0
        for obs in observers:
            obs.on_message(event)
    failed = [o.message for o in verdicts if o.code == Code.NO_STATE_FITS]
    assert not failed, failed
    judged = [o for o in verdicts if "motor_current_z" in o.values]
    assert len(judged) >= 50, [o.message for o in verdicts[-3:]]  # judged, not blind
    assert all("/motor current ~" in o.message and "holds" in o.message for o in judged)


def test_changes_first_a_climbing_level_only_as_an_identity():
    assert _climbing_choice(rates_r2=R2_MIN, level_r2=0.999) == "changes"
    assert _climbing_choice(rates_r2=0.1, level_r2=LEVEL_IDENTITY) == "level"
    # the skidsteer battery voltage against the wheel angles: the level explained more of
    # two minutes by chance (the heading), the changes too little: not related
    assert _climbing_choice(rates_r2=0.72, level_r2=0.89) is None
