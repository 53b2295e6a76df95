"""Realistic motion for correlated-sensor robots (issue 22): operating modes, loads,
integrals (a discharging battery, an odometer), transport lags and array fields."""

from __future__ import annotations

import numpy as np
import pytest

from blackbox.config.node import ConfigError
from blackbox.events import Interest, MessageArrival
from blackbox.sources.sim import Fault, SimulatedSource, Topology, open_sim, random_campaign
from blackbox.sources.sim.robot import BUILTIN_ROBOTS

DIFFDRIVE = Topology.load(BUILTIN_ROBOTS["diffdrive"])


def series(source: SimulatedSource, topic: str, fields: list[str],
           until: float) -> np.ndarray:
    """Rows of (time, field...) of every message of ``topic`` up to ``until``."""
    source.start(Interest(decoded=frozenset({topic})))
    rows = []
    for k in range(1, int(until) + 1):
        for e in source.poll(float(k)):
            if type(e) is MessageArrival and e.topic == topic:
                row = [e.time]
                for f in fields:
                    msg = e.value
                    for part in f.split("."):
                        name, _, index = part.partition("[")
                        msg = getattr(msg, name)
                        if index:
                            msg = msg[int(index[:-1])]
                    row.append(float(msg))
                rows.append(row)
    return np.array(rows)


def test_diffdrive_stands_drives_and_turns_and_the_modes_are_its_ground_truth() -> None:
    source = SimulatedSource(DIFFDRIVE, seed=0)
    odom = series(source, "/odom", ["twist.twist.linear.x"], 600.0)
    schedule = source.motion.schedule
    assert schedule is not None
    modes = {name for _, name in schedule.segments(600.0)}
    assert modes == {"stand", "straight", "turn"}
    ramp = schedule.plan.ramp
    standing = [v for t, v in odom if schedule.mode_at(t) == "stand"
                and schedule.mode_at(t - ramp) == "stand"]
    driving = [v for t, v in odom if schedule.mode_at(t) == "straight"]
    assert len(standing) > 200 and len(driving) > 200
    assert np.std(standing) < 0.03                       # noise only (0.02)
    assert np.std(driving) > 0.2                         # the motion itself


def test_each_seed_drives_its_own_schedule_and_a_seed_repeats_it() -> None:
    a = SimulatedSource(DIFFDRIVE, seed=1).motion.schedule
    b = SimulatedSource(DIFFDRIVE, seed=1).motion.schedule
    c = SimulatedSource(DIFFDRIVE, seed=2).motion.schedule
    assert a is not None and b is not None and c is not None
    assert a.segments(900.0) == b.segments(900.0) != c.segments(900.0)


def test_battery_voltage_sags_with_current_and_falls_as_the_pack_discharges() -> None:
    rows = series(SimulatedSource(DIFFDRIVE, seed=4), "/battery",
                  ["voltage", "current", "percentage"], 1800.0)
    t, volts, amps, percent = rows.T
    # voltage = a + b * current + c * t explains nearly everything (R^2 > 0.95) ...
    design = np.column_stack([np.ones_like(t), amps, t])
    coef, *_ = np.linalg.lstsq(design, volts, rcond=None)
    residual = volts - design @ coef
    assert 1 - residual.var() / volts.var() > 0.95
    assert coef[1] == pytest.approx(-0.08, rel=0.2)      # internal resistance
    assert coef[2] < 0                                   # and it falls over time
    # ... so a two-minute band learned at the start is left within the half hour
    early = volts[t < 120]
    late = volts[t > 1700]
    assert np.mean(late) < np.mean(early) - 0.3
    assert np.all(np.diff(percent[:: 25]) < 0.002) and percent[-1] < percent[0] - 0.05
    assert amps.min() > 1.3 and amps.max() > 3.0         # standing costs less than driving


def test_a_lagged_measurement_follows_the_motion_later() -> None:
    text = """
name: lagged
motion:
  v: {sines: [{amplitude: 1.0, period: 10.0}]}
nodes: [{name: /a}, {name: /b}]
topics:
  - {name: /now, type: std_msgs/Float64, publisher: /a, rate: 100, value: {follows: {v: 1.0}}}
  - {name: /late, type: std_msgs/Float64, publisher: /b, rate: 100,
     value: {follows: {v: 1.0}, lag: 0.25}}
"""
    robot = Topology.parse(text)
    now = series(SimulatedSource(robot), "/now", ["data"], 30.0)
    late = series(SimulatedSource(robot), "/late", ["data"], 30.0)
    expected = np.sin(2 * np.pi * (late[:, 0] - 0.25) / 10.0)
    assert np.allclose(late[late[:, 0] > 0.25, 1], expected[late[:, 0] > 0.25])
    assert np.allclose(now[:, 1], np.sin(2 * np.pi * now[:, 0] / 10.0))


ARRAY_ROBOT = """
name: arrays
modes:
  seed: 3
  plan: [{name: go, duration: [5, 10]}, {name: halt, duration: [5, 10]}]
motion:
  v: {mean: 1.0, modes: {halt: 0.0}}
  distance: {integral: {v: 1.0}}
  heat: {integral: {v: 2.0}, tau: 50.0}
nodes: [{name: /joints}]
topics:
  - name: /joint_states
    type: sensor_msgs/JointState
    publisher: /joints
    rate: 50
    value:
      fields:
        - {field: "velocity[0]", follows: {v: 2.0}}
        - {field: "velocity[1]", follows: {v: 2.0}, noise: 0.01, distribution: gauss}
        - {field: "position[0]", follows: {distance: 2.0}}
"""


def test_array_elements_integrals_and_leaky_integrals() -> None:
    robot = Topology.parse(ARRAY_ROBOT)
    source = SimulatedSource(robot)
    rows = series(source, "/joint_states", ["velocity[0]", "velocity[1]", "position[0]"], 60.0)
    t, vel0, vel1, pos0 = rows.T
    schedule = source.motion.schedule
    assert schedule is not None
    settled = np.array([schedule.mode_at(x) == schedule.mode_at(x - 1.0) for x in t])
    halted = np.array([schedule.mode_at(x) == "halt" for x in t])
    assert np.all(vel0[settled & halted] == 0.0) and np.all(vel0[settled & ~halted] == 2.0)
    assert np.all(np.diff(pos0) >= -1e-9)                # an odometer never goes back
    assert pos0[-1] == pytest.approx(np.trapezoid(vel0, t), rel=0.02)
    assert np.std(vel1 - vel0) == pytest.approx(0.01, rel=0.3)
    motion = source.motion
    assert motion.at("heat", 1000.0) == pytest.approx(motion.at("heat", 1000.0))
    assert 0 < motion.at("heat", 60.0) < 2.0 * 50.0      # leaks towards 2 * v * tau at most


def test_a_value_fault_on_one_array_element_leaves_the_others() -> None:
    robot = Topology.parse(ARRAY_ROBOT)
    faulty = SimulatedSource(robot, [Fault("offset", "/joint_states", 10.0, 20.0,
                                           {"value": 5.0}, field="velocity[1]")])
    healthy = SimulatedSource(robot)
    fields = ["velocity[0]", "velocity[1]", "position[0]"]
    a = series(faulty, "/joint_states", fields, 30.0)
    b = series(healthy, "/joint_states", fields, 30.0)
    inside = (a[:, 0] >= 10.0) & (a[:, 0] < 20.0)
    assert np.allclose(a[inside, 2] - b[inside, 2], 5.0)
    assert np.array_equal(a[:, [0, 1, 3]], b[:, [0, 1, 3]])
    assert faulty.ground_truth[0].field == "velocity[1]"
    assert faulty.ground_truth[0].to_dict()["field"] == "velocity[1]"


def test_random_value_faults_on_a_multi_field_topic_name_one_field() -> None:
    faults = random_campaign(DIFFDRIVE, 900.0, seed=0, kinds=["offset", "noise", "stuck"])
    battery = [f for f in faults if f.component == "/battery"]
    assert battery and all(f.field in ("voltage", "current", "percentage") for f in battery)
    assert all(f.field is None for f in faults if f.component != "/battery")


@pytest.mark.parametrize(("change", "path", "message"), [
    (("velocity[1]", "velocity[x]"), "topics[0].value.fields[1].field", "bad array index"),
    (("velocity[1]", "name[1]"), "topics[0].value.fields[1].field", "no numeric array field"),
    (("{halt: 0.0}", "{hlt: 0.0}"), "modes", "unknown mode 'hlt'"),
    (("integral: {v: 1.0}", "integral: {w: 1.0}"), "motion.distance.integral",
     "unknown motion signal 'w'"),
    (("tau: 50.0", "tau: 0"), "motion.heat.tau", ">"),
    (("  distance: {integral: {v: 1.0}}", "  distance: {integral: {heat: 1.0}}\n"
      "  heat2: {integral: {distance: 1.0}}"), "motion", ""),
])
def test_motion_and_field_mistakes_are_located_errors(change: tuple[str, str], path: str,
                                                      message: str) -> None:
    text = ARRAY_ROBOT.replace(*change)
    if "heat2" in text:
        text = text.replace("heat: {integral: {v: 2.0}, tau: 50.0}",
                            "heat: {integral: {heat2: 2.0}, tau: 50.0}")
    with pytest.raises(ConfigError) as info:
        Topology.parse(text, "robot.yaml")
    assert info.value.path.startswith(path), info.value
    assert message in info.value.message


def test_modes_without_a_plan_are_an_error() -> None:
    text = ARRAY_ROBOT.replace("modes:\n  seed: 3\n  plan: [{name: go, duration: [5, 10]}, "
                               "{name: halt, duration: [5, 10]}]\n", "")
    with pytest.raises(ConfigError) as info:
        Topology.parse(text, "robot.yaml")
    assert "no 'modes:' section" in info.value.message


def test_the_diffdrive_uri_still_opens_and_publishes_its_battery() -> None:
    source = open_sim("sim:diffdrive", seed=2)
    rows = series(source, "/battery", ["voltage"], 10.0)
    assert 45 <= len(rows) <= 55 and 24.0 < rows[:, 1].min() < rows[:, 1].max() < 25.5


def test_skidsteer_is_a_different_correlated_sensor_robot() -> None:
    robot = Topology.load(BUILTIN_ROBOTS["skidsteer"])
    rates = {t.name: t.rate for t in robot.topics.values()}
    assert rates["/imu/data"] == 200.0 and rates["/joint_states"] == 50.0
    assert rates["/gps/vel"] == 10.0 and rates["/battery_state"] == 1.0
    source = open_sim("sim:skidsteer", seed=1)
    joints = series(source, "/joint_states", ["velocity[0]", "velocity[1]", "position[1]"],
                    300.0)
    t, left, right, angle = joints.T
    speed = (left + right) / 2 * 0.15                     # v, from the wheels
    yaw = (right - left) / 2 * 0.15 / 0.3                 # w, from the wheels
    motion = source.motion
    v = np.array([motion.at("v", x - 0.02) for x in t])
    w = np.array([motion.at("w", x - 0.02) for x in t])
    assert np.corrcoef(speed, v)[0, 1] > 0.99 and np.corrcoef(yaw, w)[0, 1] > 0.95
    assert angle[-1] > angle[0] + 50                      # the wheels turned many times
    odo = series(open_sim("sim:skidsteer", seed=1), "/odometer", ["data"], 300.0)
    assert np.all(np.diff(odo[:, 1]) >= 0) and odo[-1, 1] > odo[0, 1] + 1000
    assert np.all(odo[:, 1] == np.round(odo[:, 1]))       # whole centimetres
    temp = series(open_sim("sim:skidsteer", seed=1), "/motor_temperature",
                  ["temperature"], 900.0)
    assert np.mean(temp[-60:, 1]) > np.mean(temp[:60, 1]) + 5.0   # the motors warm
