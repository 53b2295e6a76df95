"""scores observer: a numeric field of every message, filtered and judged by states."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from rosbags.typesys import Stores, get_typestore

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS

# Figure 6.1 of the thesis in the native format
CONFIG = """\
type: scores
topic: /signal
{extra}
filter: {{type: ewma, window_size: 20, decay_rate: 0.05, deviation: std_deviation}}
states:
  - number: 1
    name: ok
    score:
      type: nominal_value
      value: {{type: gauss, mean: 15.0, std_deviation: 0.5}}
"""


def build(extra: str = ""):
    return OBSERVERS["scores"].build(ConfigNode.parse(CONFIG.format(extra=extra), "t.yaml"))


def arrival(t: float, value: object, topic: str = "/signal") -> MessageArrival:
    return MessageArrival(t, topic, "/sensor", 8, value=value)


def test_signal_around_15_fits_ok() -> None:
    sc = build()
    for i, x in enumerate([15.0, 15.2, 14.8, 15.1]):
        sc.on_message(arrival(i * 0.1, SimpleNamespace(data=x)))
    [obs] = sc.evaluate(0.5)
    # ewma over the window in arrival order, decay 0.05
    expected = 15.0
    for x in (15.2, 14.8, 15.1):
        expected += 0.05 * (x - expected)
    assert obs.code == Code.GENERAL_OK
    assert obs.states == (State(1, "ok"),)
    assert obs.resource == Resource(topic="/signal")
    assert obs.values["score"] == pytest.approx(expected)
    # sample deviation: mean 15.025, squared deviations sum to 0.0875
    assert obs.values["score_deviation"] == pytest.approx((0.0875 / 3) ** 0.5)
    assert obs.message == f"score {expected:.4g} fits 'ok'"


def test_signal_off_its_value_fits_no_state() -> None:
    sc = build()
    sc.on_message(arrival(0.0, SimpleNamespace(data=17.0)))
    [obs] = sc.evaluate(1.0)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.message == "score 17 fits no state (expected 'ok')"


def test_decoding_is_lazy_and_happens_once() -> None:
    sc = build()
    calls = []

    def decode() -> SimpleNamespace:
        calls.append(1)
        return SimpleNamespace(data=15.0)

    msg = MessageArrival(0.0, "/signal", "/sensor", 8, decode=decode)
    assert calls == []
    sc.on_message(msg)
    sc.on_message(msg)
    assert calls == [1]


def test_rosbags_message_and_nested_field() -> None:
    store = get_typestore(Stores.ROS1_NOETIC)
    point = store.types["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=15.1)
    sc = build("field: point.z")
    sc.on_message(arrival(0.0, SimpleNamespace(point=point)))
    [obs] = sc.evaluate(1.0)
    assert obs.values["score"] == pytest.approx(15.1)
    assert sc.describe().startswith(
        "scores /signal field point.z: ewma (decay_rate 0.05, window 20")


def test_unreadable_values_are_skipped_and_reported_as_errors() -> None:
    sc = build()
    sc.on_message(arrival(0.0, SimpleNamespace(data=15.0)))
    sc.on_message(arrival(0.1, SimpleNamespace(data="fifteen")))
    sc.on_message(arrival(0.2, SimpleNamespace(value=15.0)))
    [obs] = sc.evaluate(1.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message == ("2 of 3 messages since the last evaluation unreadable: "
                           "field path 'data': message has no field 'data'")
    assert obs.values == {"skipped": 2.0, "score": 15.0}
    [obs] = sc.evaluate(2.0)  # nothing unreadable since: the good sample judges again
    assert obs.code == Code.GENERAL_OK
    assert obs.values["score"] == 15.0


def test_nan_is_not_a_score() -> None:
    sc = build()
    sc.on_message(arrival(0.0, SimpleNamespace(data=float("nan"))))
    [obs] = sc.evaluate(1.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message.endswith("data is nan, not a finite number")
    [obs] = sc.evaluate(2.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for first message"


def test_a_topic_the_source_cannot_decode_is_not_available() -> None:
    sc = build()
    sc.on_message(MessageArrival(0.0, "/signal", "/sensor", 8))  # no decoder: value None
    [obs] = sc.evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message.endswith("the source cannot decode this topic")


def test_interest_asks_for_decoded_values() -> None:
    assert build().interest() == Interest(decoded=frozenset({"/signal"}))


@pytest.mark.parametrize(("extra", "message"), [
    ("field: 'a..b'", "invalid field path 'a..b'"),
    ("field: 3", "expected a non-empty string"),
    ("publishers: [/a]", "unknown key 'publishers'"),
])
def test_config_errors(extra: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        build(extra)
    assert err.value.line == 3
    assert message in err.value.message


def test_state_over_a_wrong_quantity_is_an_error() -> None:
    text = "type: scores\ntopic: /s\nstates:\n  - {number: 1, name: ok, period: {}}\n"
    with pytest.raises(ConfigError) as err:
        OBSERVERS["scores"].build(ConfigNode.parse(text, "t.yaml"))
    assert err.value.line == 4
    assert "unknown key 'period'" in err.value.message


def test_a_message_that_fails_to_decode_is_an_error_not_a_crash() -> None:
    sc = build()

    def garbage() -> object:
        raise ValueError("buffer too short")

    sc.on_message(MessageArrival(0.0, "/signal", "/sensor", 3, decode=garbage))
    [obs] = sc.evaluate(1.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message.endswith("message does not decode: buffer too short")
