"""timestamp observer: message age = arrival time - header.stamp."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from rosbags.typesys import Stores, get_typestore

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS
from blackbox.observe.observers.timestamp import stamp_seconds

CONFIG = """\
type: timestamp
topic: /camera/image
{extra}
filter: {{type: mean, window_size: 3}}
states:
  - number: 1
    name: fresh
    age: {{value: {{type: less_than, less_than: 0.1}}}}
"""

STORE = get_typestore(Stores.ROS1_NOETIC)
Time = STORE.types["builtin_interfaces/msg/Time"]
Header = STORE.types["std_msgs/msg/Header"]


def build(extra: str = ""):
    return OBSERVERS["timestamp"].build(ConfigNode.parse(CONFIG.format(extra=extra), "t.yaml"))


def stamped(arrival: float, stamp: object, publisher: str = "/cam") -> MessageArrival:
    value = SimpleNamespace(header=SimpleNamespace(stamp=stamp))
    return MessageArrival(arrival, "/camera/image", publisher, 10, value=value)


def test_stamp_shapes() -> None:
    assert stamp_seconds(Time(sec=100, nanosec=250_000_000)) == 100.25
    assert stamp_seconds(SimpleNamespace(secs=7, nsecs=500_000_000)) == 7.5
    assert stamp_seconds({"sec": 1, "nanosec": 0}) == 1.0
    assert stamp_seconds(3.5) == 3.5
    with pytest.raises(ValueError, match=r"header\.stamp is str 'now', not a time"):
        stamp_seconds("now")


def test_fresh_images_fit() -> None:
    ts = build()
    for k, age in enumerate([0.02, 0.03, 0.04]):
        t = 100.0 + k
        header = Header(seq=k, stamp=Time(sec=int(t - age), nanosec=round((t - age) % 1 * 1e9)),
                        frame_id="cam")
        ts.on_message(MessageArrival(t, "/camera/image", "/cam", 10,
                                     value=SimpleNamespace(header=header)))
    [obs] = ts.evaluate(103.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.states == (State(1, "fresh"),)
    assert obs.resource == Resource(topic="/camera/image")
    assert obs.values["age"] == pytest.approx(0.03, abs=1e-6)
    assert obs.message == "age 0.03 s fits 'fresh'"


def test_late_messages_fit_no_state() -> None:
    ts = build()
    for k in range(3):
        ts.on_message(stamped(10.0 + k, SimpleNamespace(secs=9 + k, nsecs=500_000_000)))
    [obs] = ts.evaluate(13.0)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.values["age"] == pytest.approx(0.5)


def test_unset_and_unreadable_stamps_are_errors() -> None:
    ts = build()
    ts.on_message(stamped(1.0, Time(sec=0, nanosec=0)))
    [obs] = ts.evaluate(2.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message.endswith("header.stamp is zero (not set by the publisher)")
    ts.on_message(MessageArrival(2.5, "/camera/image", "/cam", 10, value=SimpleNamespace(x=1)))
    [obs] = ts.evaluate(3.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message.endswith("field path 'header.stamp': message has no field 'header'")


def test_publisher_group() -> None:
    ts = build("publishers: [/cam_left]")
    ts.on_message(stamped(5.0, 4.99, "/cam_left"))
    ts.on_message(stamped(5.0, 3.0, "/cam_right"))
    [obs] = ts.evaluate(6.0)
    assert obs.resource == Resource(topic="/camera/image", publishers=("/cam_left",))
    assert obs.values["age"] == pytest.approx(0.01)
    assert obs.code == Code.GENERAL_OK


def test_not_available_before_first_message() -> None:
    [obs] = build().evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for first message"


def test_interest_and_config_error() -> None:
    assert build().interest() == Interest(decoded=frozenset({"/camera/image"}))
    with pytest.raises(ConfigError) as err:
        build("field: header.stamp")
    assert err.value.line == 3
    assert "unknown key 'field'" in err.value.message
