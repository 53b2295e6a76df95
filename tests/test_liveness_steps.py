"""A step is not a noise burst (issue 22, learned liveness), as specifications.

When an offset or a scale fault ends, the value goes back in one sample: one large first
difference, two large second differences. A learned noise check took the mean of the
squared second differences of a block, so those two alone lifted the block by ten
standard deviations and raised a noise burst seconds after the fault had ended (a false
alarm in both real ROS 2 campaigns of round rel22b: a battery voltage going back after a
0.74 scale). Learning now caps each squared second difference at ``NOISE_CAP`` times the
healthy mean, while learning and while judging: one step moves a block a little, a
noise burst (many large differences) still lifts every block.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blackbox.events import GraphSnapshot, MessageArrival, NodeInfo, TopicInfo
from blackbox.learn import learn_from, render_config
from blackbox.model import Code, Observation
from blackbox.observe.build import build_observer, load_config_text
from blackbox.observe.observers.liveness import LivenessObserver
from blackbox.sources.memory import MemorySource

Fault = Callable[[float, float], float]
"""``fault(t, x)``: what the sensor reports at ``t`` for the true reading ``x``."""


@dataclass(frozen=True)
class Battery:
    voltage: float


@dataclass(frozen=True)
class Wheel:
    speed: float


def healthy(t: float, x: float) -> float:
    return x


def robot(seconds: float, *, seed: int, battery: Fault = healthy, wheel: Fault = healthy,
          start: float = 0.0) -> list[object]:
    """A 1 Hz battery voltage discharging slowly (noise 0.01 V) and a 20 Hz wheel speed
    following a smooth drive (noise 0.01 m/s), each through its ``Fault``."""
    rng = np.random.default_rng(seed)
    nodes = {"/battery_monitor": NodeInfo("/battery_monitor", True, 101),
             "/wheel_driver": NodeInfo("/wheel_driver", True, 102)}
    topics = {"/battery": TopicInfo("/battery", "sensor_msgs/BatteryState",
                                    ("/battery_monitor",), ()),
              "/wheel": TopicInfo("/wheel", "std_msgs/Float64", ("/wheel_driver",), ())}
    events: list[object] = [GraphSnapshot(start + t, nodes, topics)
                            for t in range(int(seconds) + 1)]
    k = 0
    while k / 20.0 < seconds:
        t = start + k / 20.0 + 0.003
        speed = 0.6 + 0.4 * math.sin(2 * math.pi * t / 23.0) + rng.normal(0, 0.01)
        events.append(MessageArrival(t, "/wheel", "/wheel_driver", 8,
                                     value=Wheel(wheel(t, speed))))
        if k % 20 == 0:
            volts = 12.4 - 0.0002 * t + rng.normal(0, 0.01)
            events.append(MessageArrival(t + 0.011, "/battery", "/battery_monitor", 8,
                                         value=Battery(battery(t, volts))))
        k += 1
    return sorted(events, key=lambda e: e.time)  # type: ignore[attr-defined,no-any-return]


def liveness(events: list[object]) -> dict[str, LivenessObserver]:
    """The liveness observers ``blackbox learn`` writes from two minutes of ``events``,
    by topic."""
    result = learn_from(lambda: MemorySource(events), 120.0)  # type: ignore[arg-type]
    config = load_config_text(render_config(result, "r", "r.model.yaml", "now"), "r.yaml")
    out: dict[str, LivenessObserver] = {}
    for entry in config.observers:
        if entry.to_python()["type"] == "liveness":
            obs = build_observer(entry)
            assert isinstance(obs, LivenessObserver)
            out[obs.topic] = obs
    return out


def replay(obs: LivenessObserver, events: list[object]) -> list[Observation]:
    """``obs`` over the messages of ``events``, evaluated once a second."""
    out: list[Observation] = []
    next_eval = math.nan
    for e in events:
        if not isinstance(e, MessageArrival):
            continue
        if math.isnan(next_eval):
            next_eval = math.floor(e.time) + 1.0
        while e.time >= next_eval:
            out.extend(obs.evaluate(next_eval))
            next_eval += 1.0
        obs.on_message(e)
    return out


def failed(verdicts: list[Observation], after: float = -math.inf) -> list[Observation]:
    return [o for o in verdicts if o.code == Code.NO_STATE_FITS and o.time > after]


def between(a: float, b: float, fault: Callable[[float], float]) -> Fault:
    return lambda t, x: fault(x) if a <= t < b else x


def learned() -> dict[str, LivenessObserver]:
    observers = liveness(robot(120.0, seed=1))
    assert set(observers) == {"/battery", "/wheel"}, observers
    return observers


def test_the_noise_check_is_learned_with_a_cap_on_each_squared_difference() -> None:
    result = learn_from(lambda: MemorySource(robot(120.0, seed=1)),  # type: ignore[arg-type]
                        120.0)
    text = render_config(result, "r", "r.model.yaml", "now")
    assert "cap:" in text and "a step is not a burst" in text.replace("\n  #   ", " "), text


def test_a_1_hz_voltage_going_back_after_a_scale_fault_raises_no_noise_burst() -> None:
    """The real robots' case: 12.4 V scaled by 0.74 for 30 s, then back (a 3.2 V step,
    320 noise std)."""
    obs = learned()["/battery"]
    out = replay(obs, robot(300.0, seed=2, start=200.0,
                            battery=between(300.0, 330.0, lambda x: 0.74 * x)))
    assert failed(out, after=333.0) == [], [(o.time, o.message)
                                            for o in failed(out, after=333.0)]


def test_a_20_hz_speed_going_back_after_an_offset_raises_no_noise_burst() -> None:
    obs = learned()["/wheel"]
    out = replay(obs, robot(120.0, seed=3, start=200.0,
                            wheel=between(250.0, 270.0, lambda x: x + 0.3)))
    assert failed(out, after=272.0) == [], [(o.time, o.message)
                                            for o in failed(out, after=272.0)]


def test_a_noise_burst_on_a_1_hz_voltage_is_still_found() -> None:
    """Four times the voltage's noise from 300 s on: many large differences."""
    obs = learned()["/battery"]
    rng = np.random.default_rng(9)
    out = replay(obs, robot(200.0, seed=4, start=200.0,
                            battery=between(300.0, 400.0,
                                            lambda x: x + float(rng.normal(0, 0.04)))))
    assert failed(out, after=200.0), "the burst was never found"
    first = failed(out, after=200.0)[0]
    assert 300.0 < first.time <= 340.0 and "noise burst" in first.message, first


def test_a_noise_burst_on_a_20_hz_speed_is_still_found_within_three_seconds() -> None:
    obs = learned()["/wheel"]
    rng = np.random.default_rng(10)
    out = replay(obs, robot(100.0, seed=5, start=200.0,
                            wheel=between(250.0, 270.0,
                                          lambda x: x + float(rng.normal(0, 0.04)))))
    first = failed(out, after=200.0)
    assert first, "the burst was never found"
    assert 250.0 < first[0].time <= 253.0 and "noise burst" in first[0].message, first[0]
