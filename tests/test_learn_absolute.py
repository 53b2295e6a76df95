"""A signal that grows with another's size in either direction (issue 22): a battery or
motor current draws as much turning left as turning right, so no linear fit of the yaw
rate relates it, and its faults went unseen. Learning tries the absolute values of
another topic's signals for a target that no linear relation to another topic explains,
and keeps them by the same held-out R² as any relation."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blackbox.events import GraphSnapshot, MessageArrival, NodeInfo, TopicInfo
from blackbox.model import Code
from test_learn_relations_bad_input import judge, learned_text, observer_from, relations_of, yaw

TOPICS = {"/cmd": "/teleop", "/imu": "/imu_driver", "/power": "/power_monitor"}


@dataclass(frozen=True)
class Cmd:
    w: float


@dataclass(frozen=True)
class Imu:
    z: float


@dataclass(frozen=True)
class Power:
    current: float


def graph(t: float) -> GraphSnapshot:
    nodes = {n: NodeInfo(n, True, 100 + i) for i, n in enumerate(TOPICS.values())}
    topics = {t_: TopicInfo(t_, "std_msgs/Float64", (n,), ()) for t_, n in TOPICS.items()}
    return GraphSnapshot(t, nodes, topics)


def robot(seconds: float, *, start: float = 0.0, seed: int = 0, offset_from: float = math.inf,
          offset: float = 0.0) -> list:
    """A command and an IMU measuring one yaw rate, and a current ``1 + 3 |w|`` (10 Hz)."""
    rng = np.random.default_rng(seed)
    events: list = [graph(start + float(t)) for t in range(int(seconds) + 1)]
    k = 0
    while k / 20.0 < seconds:
        t = start + k / 20.0 + 0.003
        w = yaw(t)
        events.append(MessageArrival(t, "/cmd", "/teleop", 8, value=Cmd(w + rng.normal(0, 0.005))))
        events.append(MessageArrival(t + 0.011, "/imu", "/imu_driver", 8,
                                     value=Imu(w + rng.normal(0, 0.02))))
        if k % 2 == 0:
            current = 1.0 + 3.0 * abs(w) + rng.normal(0, 0.02)
            if t >= offset_from:
                current += offset
            events.append(MessageArrival(t + 0.02, "/power", "/power_monitor", 8,
                                         value=Power(current)))
        k += 1
    return sorted(events, key=lambda e: e.time)


def test_a_current_that_grows_with_the_turn_either_way_is_related_through_absolute_values():
    _, text = learned_text(robot(120.0), 120.0)
    current = [r for entry in relations_of(text) for r in entry["relations"]
               if r["target"] == {"topic": "/power", "field": "current"}]
    assert current, text
    inputs = [(i["topic"], i["field"], i.get("abs", False)) for r in current
              for i in r["inputs"]]
    assert ("/cmd", "w", True) in inputs or ("/imu", "z", True) in inputs, inputs
    # the IMU is linear in the command: no absolute value where none is needed
    imu = [r for entry in relations_of(text) for r in entry["relations"]
           if r["target"] == {"topic": "/imu", "field": "z"}]
    assert imu and not any(i.get("abs") for r in imu for i in r["inputs"]), imu
    assert "|/cmd w|" in text or "|/imu z|" in text  # the comment says which


def test_the_learned_absolute_relation_holds_while_healthy_and_sees_an_offset_of_the_current():
    _, text = learned_text(robot(120.0), 120.0)
    entry = next(e for e in relations_of(text)
                 if any(r["target"]["topic"] == "/power" for r in e["relations"]))
    import yaml

    obs = observer_from(yaml.safe_dump({"version": 1, "robot": {"id": "r"},
                                        "observers": [entry]}))
    healthy = judge(obs, robot(60.0, start=200.0, seed=3), 260.0)
    assert not any(o.code == Code.NO_STATE_FITS for o in healthy), \
        [o.message for o in healthy if o.code == Code.NO_STATE_FITS]
    assert any(o.code == Code.GENERAL_OK for o in healthy), [o.message for o in healthy]
    faulty = judge(obs, robot(20.0, start=300.0, seed=4, offset_from=305.0, offset=0.3),
                   320.0)
    assert any(o.code == Code.NO_STATE_FITS and "/power current disagrees" in o.message
               for o in faulty), [o.message for o in faulty]
