"""The correlated-sensor robot (issue 18): motion signals in the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from blackbox.config.node import ConfigError
from blackbox.events import Interest, MessageArrival
from blackbox.sources.sim import Fault, SimulatedSource, Topology, open_sim
from blackbox.sources.sim.robot import BUILTIN_ROBOTS


def _values(source: SimulatedSource, topic: str, field: str, until: float) -> np.ndarray:
    source.start(Interest(decoded=frozenset({topic})))
    out = []
    for e in source.poll(until):
        if type(e) is MessageArrival and e.topic == topic:
            msg = e.value
            for part in field.split("."):
                msg = getattr(msg, part)
            out.append(float(msg))
    return np.array(out)


def test_sensors_of_one_motion_are_correlated_and_of_two_motions_are_not() -> None:
    cmd = _values(open_sim("sim:diffdrive"), "/cmd_vel", "linear.x", 60.0)
    odom = _values(open_sim("sim:diffdrive"), "/odom", "twist.twist.linear.x", 60.0)
    imu = _values(open_sim("sim:diffdrive"), "/imu/data", "angular_velocity.z", 60.0)
    n = min(len(cmd), len(odom), len(imu))
    assert np.corrcoef(cmd[:n], odom[:n])[0, 1] > 0.95
    assert abs(np.corrcoef(cmd[:n], imu[:n])[0, 1]) < 0.5


def test_a_value_fault_acts_on_the_followed_motion() -> None:
    topo = Topology.load(BUILTIN_ROBOTS["diffdrive"])
    stuck = SimulatedSource(topo, [Fault("stuck", "/odom", 10.0, 20.0)])
    values = _values(stuck, "/odom", "twist.twist.linear.x", 20.0)
    assert len(set(values[-150:])) == 1          # frozen during the fault
    assert len(set(values[:150])) > 100          # moving before it


def test_unknown_motion_signal_is_a_located_error() -> None:
    text = """
name: r
nodes: [{name: /n}]
topics:
  - {name: /t, type: std_msgs/Float64, publisher: /n, rate: 10, value: {follows: {nope: 1}}}
"""
    with pytest.raises(ConfigError) as err:
        Topology.parse(text, "robot.yaml")
    assert "nope" in err.value.message and err.value.line == 5
