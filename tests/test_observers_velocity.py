"""velocity observer: two motion sources must agree on the robot's accelerations."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS
from blackbox.observe.observers.velocity import regression_slope

CONFIG = """\
type: velocity
source_a: {{type: odometry, topic: /odom}}
source_b: {{type: {kind_b}, topic: /imu}}
acceleration_window_size: 3
{extra}
states:
  - number: 1
    name: consistent
    x: {{value: {{type: gauss, mean: 0.0, std_deviation: 0.1}}}}
    rot_z: {{value: {{type: gauss, mean: 0.0, std_deviation: 0.1}}}}
"""


def build(kind_b: str = "imu", extra: str = ""):
    return OBSERVERS["velocity"].build(ConfigNode.parse(CONFIG.format(kind_b=kind_b, extra=extra),
                                                  "t.yaml"))


def vec(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> SimpleNamespace:
    return SimpleNamespace(x=x, y=y, z=z)


def odometry(vx: float, wz: float) -> SimpleNamespace:
    return SimpleNamespace(twist=SimpleNamespace(twist=SimpleNamespace(linear=vec(vx),
                                                                       angular=vec(z=wz))))


def imu(ax: float, wz: float) -> SimpleNamespace:
    return SimpleNamespace(linear_acceleration=vec(ax, 0.0, 9.81), angular_velocity=vec(z=wz))


def drive(observer, imu_ax, n: int = 6) -> None:
    """Accelerate at 2 m/s^2 and 0.5 rad/s^2: odometry at 0, 0.1, ...; imu 0.05 s later."""
    for k in range(n):
        t = k * 0.1
        observer.on_message(MessageArrival(t, "/odom", "/base", 10, value=odometry(2 * t, 0.5 * t)))
        ti = t + 0.05
        observer.on_message(MessageArrival(ti, "/imu", "/imu", 10, value=imu(imu_ax, 0.5 * ti)))


def test_regression_slope() -> None:
    # mean t 1.5, mean v 2.75: sum dt*dv = 5.5, sum dt^2 = 5
    assert regression_slope([0.0, 1.0, 2.0, 3.0], [1.0, 3.0, 2.0, 5.0]) == pytest.approx(1.1)
    assert regression_slope([1.0], [1.0]) is None
    assert regression_slope([1.0, 1.0], [1.0, 2.0]) is None


def test_agreeing_sources_are_consistent() -> None:
    vel = build()
    drive(vel, imu_ax=2.0)
    [obs] = vel.evaluate(1.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.states == (State(1, "consistent"),)
    assert obs.resource == Resource(topic="/odom", topic_b="/imu")
    assert obs.values["x"] == pytest.approx(0.0, abs=1e-9)
    assert obs.values["rot_z"] == pytest.approx(0.0, abs=1e-9)
    assert obs.values["z"] == pytest.approx(-9.81)  # gravity on the imu; not in the states
    assert obs.message.startswith("acceleration difference x ")


def test_stuck_imu_is_inconsistent() -> None:
    vel = build()
    drive(vel, imu_ax=0.0)
    [obs] = vel.evaluate(1.0)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.values["x"] == pytest.approx(2.0)


def test_acceleration_window_forgets_old_motion() -> None:
    vel = build(kind_b="twist")
    for k in range(6):  # odometry accelerates until 0.3 s, then holds 0.6 m/s
        t = k * 0.1
        v = 2 * min(t, 0.3)
        vel.on_message(MessageArrival(t, "/odom", "/base", 10, value=odometry(v, 0.0)))
        vel.on_message(MessageArrival(t, "/imu", "/base", 10,
                                      value={"linear": {"x": 0.6, "y": 0, "z": 0},
                                             "angular": {"x": 0, "y": 0, "z": 0}}))
    [obs] = vel.evaluate(1.0)
    # last three odometry velocities 0.6, 0.6, 0.6 -> acceleration 0 like the constant twist
    assert obs.values["x"] == pytest.approx(0.0)
    assert obs.code == Code.GENERAL_OK


def test_not_available_until_both_sources_have_estimates() -> None:
    vel = build()
    vel.on_message(MessageArrival(0.0, "/odom", "/base", 10, value=odometry(0.0, 0.0)))
    vel.on_message(MessageArrival(0.05, "/imu", "/imu", 10, value=imu(0.0, 0.0)))
    [obs] = vel.evaluate(0.1)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for messages on both sources (/odom 1 of 2, /imu 1 of 2)"


def test_unreadable_source_message_is_an_error() -> None:
    vel = build()
    vel.on_message(MessageArrival(0.0, "/imu", "/imu", 10, value=SimpleNamespace(orientation=1)))
    [obs] = vel.evaluate(1.0)
    assert obs.code == Code.GENERAL_ERROR
    assert "/imu: field path 'linear_acceleration.x'" in obs.message


def test_interest_and_switched_off_axes() -> None:
    vel = build(extra="use_roll: false\nuse_pitch: false")
    assert tuple(vel.axes) == ("x", "y", "z", "rot_z")
    assert vel.interest() == Interest(decoded=frozenset({"/odom", "/imu"}))
    assert vel.describe().startswith(
        "velocity odometry /odom vs imu /imu: acceleration over 3 messages; nofilter")


@pytest.mark.parametrize(("extra", "line", "message"), [
    ("x_filter: {type: mean, window_size: 0}", 5, "window_size must be an integer >= 1"),
    ("acceleartion_window_size: 4", 5, "did you mean 'acceleration_window_size'?"),
])
def test_config_errors(extra: str, line: int, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        build(extra=extra)
    assert err.value.line == line
    assert message in err.value.message


def test_window_of_one_cannot_give_a_slope() -> None:
    text = CONFIG.format(kind_b="imu", extra="").replace("window_size: 3", "window_size: 1")
    with pytest.raises(ConfigError) as err:
        OBSERVERS["velocity"].build(ConfigNode.parse(text, "t.yaml"))
    assert err.value.line == 4
    assert "must be >= 2" in err.value.message


def test_missing_source() -> None:
    with pytest.raises(ConfigError, match="missing required key 'source_b'"):
        OBSERVERS["velocity"].build(ConfigNode.parse(
            "type: velocity\nsource_a: {type: imu, topic: /imu}\n", "t.yaml"))
