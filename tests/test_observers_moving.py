"""moving observer: per-axis motion of one source tells moving from idle."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from rosbags.typesys import Stores, get_typestore

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS

CONFIG = """\
type: moving
source: {{type: {kind}, topic: /odom}}
{extra}
x_filter: {{type: mean, window_size: 3}}
states:
  - number: 1
    name: idle
    x: {{value: {{type: gauss, mean: 0.0, std_deviation: 0.05}}}}
    rot_z: {{value: {{type: gauss, mean: 0.0, std_deviation: 0.05}}}}
  - number: 2
    name: moving
    x: {{value: {{type: not_in_between, lower_bound: -0.05, upper_bound: 0.05}}}}
"""


def build(kind: str = "odometry", extra: str = ""):
    text = CONFIG.format(kind=kind, extra=extra)
    return OBSERVERS["moving"].build(ConfigNode.parse(text, "t.yaml"))


def vec(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> SimpleNamespace:
    return SimpleNamespace(x=x, y=y, z=z)


def odometry(vx: float, wz: float = 0.0) -> SimpleNamespace:
    return SimpleNamespace(twist=SimpleNamespace(twist=SimpleNamespace(linear=vec(vx),
                                                                       angular=vec(z=wz))))


def feed(observer, values, topic: str = "/odom") -> None:
    for k, value in enumerate(values):
        observer.on_message(MessageArrival(k * 0.1, topic, "/base", 10, value=value))


def test_standing_robot_is_idle() -> None:
    mv = build()
    feed(mv, [odometry(0.0), odometry(0.01), odometry(-0.01)])
    [obs] = mv.evaluate(1.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.states == (State(1, "idle"),)
    assert obs.resource == Resource(topic="/odom")
    assert obs.values["x"] == pytest.approx(0.0)
    assert set(obs.values) >= {"x", "y", "z", "rot_x", "rot_y", "rot_z"}
    assert obs.message.endswith("fits 'idle'")


def test_driving_robot_is_moving() -> None:
    mv = build()
    feed(mv, [odometry(0.3), odometry(0.5), odometry(0.4)])
    [obs] = mv.evaluate(1.0)
    assert obs.states == (State(2, "moving"),)
    assert obs.values["x"] == pytest.approx(0.4)


def test_turning_on_the_spot_fits_neither() -> None:
    mv = build()
    feed(mv, [odometry(0.0, wz=0.8)])
    [obs] = mv.evaluate(1.0)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.values["rot_z"] == 0.8


def test_real_odometry_message() -> None:
    store = get_typestore(Stores.ROS1_NOETIC)
    t = store.types
    twist = t["geometry_msgs/msg/TwistWithCovariance"](
        twist=t["geometry_msgs/msg/Twist"](linear=t["geometry_msgs/msg/Vector3"](x=0.5, y=0, z=0),
                                           angular=t["geometry_msgs/msg/Vector3"](x=0, y=0, z=0)),
        covariance=[0.0] * 36)
    odom = SimpleNamespace(twist=twist)  # the part of nav_msgs/Odometry the observer reads
    mv = build()
    feed(mv, [odom])
    [obs] = mv.evaluate(1.0)
    assert obs.values["x"] == 0.5


def test_twist_and_twist_stamped_as_mappings() -> None:
    mv = build("twist")
    feed(mv, [{"linear": {"x": 0.2, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0}},
              {"header": {}, "twist": {"linear": {"x": 0.4, "y": 0, "z": 0},
                                       "angular": {"x": 0, "y": 0, "z": 0}}}])
    [obs] = mv.evaluate(1.0)
    assert obs.values["x"] == pytest.approx(0.3)


def test_imu_values_are_taken_as_they_are() -> None:
    mv = build("imu")
    feed(mv, [SimpleNamespace(linear_acceleration=vec(0.0, 0.0, 9.81),
                              angular_velocity=vec(z=0.01))])
    [obs] = mv.evaluate(1.0)
    assert obs.values["z"] == pytest.approx(9.81)
    assert obs.states == (State(1, "idle"),)


def test_unreadable_messages_are_errors() -> None:
    mv = build()
    feed(mv, [odometry(0.0), SimpleNamespace(pose=None), odometry(float("inf"))])
    [obs] = mv.evaluate(1.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message == ("2 of 3 messages since the last evaluation unreadable: "
                           "x is inf, not a finite number")


def test_not_available_before_first_message() -> None:
    [obs] = build().evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE


def test_yaw_switched_off() -> None:
    text = CONFIG.format(kind="odometry", extra="use_yaw: false").replace(
        "    rot_z: {value: {type: gauss, mean: 0.0, std_deviation: 0.05}}\n", "")
    mv = OBSERVERS["moving"].build(ConfigNode.parse(text, "t.yaml"))
    assert tuple(mv.axes) == ("x", "y", "z", "rot_x", "rot_y")
    assert mv.interest() == Interest(decoded=frozenset({"/odom"}))
    with pytest.raises(ConfigError) as err:
        build(extra="use_yaw: false")  # the idle state still checks rot_z
    assert err.value.line == 9
    assert "rot_z given but rot_z is switched off (use_yaw: false)" in err.value.message
    with pytest.raises(ConfigError) as err:
        build(extra="use_yaw: false\nrot_z_filter: {type: mean, window_size: 2}")
    assert err.value.line == 4
    assert "rot_z_filter given but rot_z is switched off" in err.value.message


@pytest.mark.parametrize(("kind", "extra", "line", "message"), [
    ("tf", "", 2, "unknown value 'tf'; expected one of odometry, twist, imu"),
    ("odometry", "use_roll: 1", 3, "expected true or false"),
    ("odometry", "sources: []", 3, "did you mean 'source'?"),
])
def test_config_errors(kind: str, extra: str, line: int, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        build(kind, extra)
    assert err.value.line == line
    assert message in err.value.message
