"""`blackbox learn --update` adds an operating mode to learned relations (issue 22 item 3):
a robot learned while always turning cannot judge its relations standing still (no
excitation, no verdict); a second healthy run that stands still adds that mode, and the
merged relation judges standing still with the noise learned there."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blackbox.events import GraphSnapshot, MessageArrival, NodeInfo, TopicInfo
from blackbox.learn import learn_from, render_config, update_config
from blackbox.model import Code
from blackbox.observe.build import build_observer, load_config_text
from blackbox.observe.observers.relation import RelationObserver
from blackbox.sources.memory import MemorySource


@dataclass(frozen=True)
class Cmd:
    w: float


@dataclass(frozen=True)
class Imu:
    z: float


def graph(t: float) -> GraphSnapshot:
    return GraphSnapshot(
        t, {"/teleop": NodeInfo("/teleop", True, 1), "/imu_driver": NodeInfo("/imu_driver",
                                                                            True, 2)},
        {"/cmd": TopicInfo("/cmd", "std_msgs/Float64", ("/teleop",), ()),
         "/imu": TopicInfo("/imu", "std_msgs/Float64", ("/imu_driver",), ())})


def robot(seconds: float, seed: int, stands: bool) -> list:
    """A command and an IMU of one yaw rate; ``stands``: every other 30 s it stands."""
    rng = np.random.default_rng(seed)
    events: list = [graph(float(t)) for t in range(int(seconds) + 1)]
    for k in range(int(seconds * 20)):
        t = k / 20 + 0.004
        still = stands and int(t // 30) % 2 == 1
        w = 0.0 if still else 0.5 * math.sin(2 * math.pi * t / 7) + 0.2 * math.sin(t)
        events.append(MessageArrival(t, "/cmd", "/teleop", 8, value=Cmd(w + rng.normal(0, .005))))
        events.append(MessageArrival(t + 0.013, "/imu", "/imu_driver", 8,
                                     value=Imu(w + rng.normal(0, 0.02))))
    return sorted(events, key=lambda e: e.time)


def relation_entry(text: str) -> dict:
    return next(e.to_python() for e in load_config_text(text, "r.yaml").observers
                if e.to_python()["type"] == "relation")


def standing_verdicts(text: str) -> list:
    config = load_config_text(text, "r.yaml")
    entry = next(e for e in config.observers if e.to_python()["type"] == "relation")
    obs = build_observer(entry)
    assert isinstance(obs, RelationObserver)
    out = []
    for e in robot(120.0, seed=9, stands=True):
        if isinstance(e, MessageArrival):
            obs.on_message(e)
            if e.topic == "/imu" and int(e.time * 20) % 20 == 0:
                out.extend(o for o in obs.evaluate(e.time) if 40.0 < o.time < 60.0)
    return out


def test_update_with_a_run_that_stands_still_adds_the_standing_mode() -> None:
    first = learn_from(lambda: MemorySource(robot(150.0, seed=1, stands=False)), 150.0)
    text = render_config(first, "r", "r.model.yaml", "first")
    before = relation_entry(text)["relations"][0]
    assert before["still"] is None
    unjudged = standing_verdicts(text)
    assert unjudged and all(o.code == Code.NOT_AVAILABLE for o in unjudged)
    assert "standing still was not seen" in unjudged[-1].message

    second = learn_from(lambda: MemorySource(robot(240.0, seed=2, stands=True)), 240.0)
    updated = update_config(text, "r.yaml", second, "r.model.yaml", "second")
    after = relation_entry(updated)["relations"][0]
    assert after["still"] is not None
    assert after["block_noise"] >= before["block_noise"]
    assert after["cusum"]["h"] >= before["cusum"]["h"]
    judged = standing_verdicts(updated)
    assert sum(o.code == Code.GENERAL_OK for o in judged) >= len(judged) - 3
    assert all(o.code != Code.NO_STATE_FITS for o in judged)
