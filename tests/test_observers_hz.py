"""hz observer: inter-arrival period of a publisher group, stalls shown at once."""

from __future__ import annotations

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS

CONFIG = """\
type: hz
topic: /scan
{extra}
filter: {{type: mean, window_size: 5}}
states:
  - number: 1
    name: ok
    period: {{type: nominal_value, value: {{type: gauss, mean: 0.1, std_deviation: 0.01}}}}
"""


def build(extra: str = ""):
    return OBSERVERS["hz"].build(ConfigNode.parse(CONFIG.format(extra=extra), "t.yaml"))


def feed(observer, times, publisher="/laser", topic="/scan"):
    for t in times:
        observer.on_message(MessageArrival(t, topic, publisher, 100))


def ticks(start: float, period: float, n: int) -> list[float]:
    return [start + i * period for i in range(n)]


def test_steady_10_hz_fits_ok() -> None:
    hz = build()
    feed(hz, ticks(0.0, 0.1, 11))
    [obs] = hz.evaluate(1.05)
    assert obs.code == Code.GENERAL_OK
    assert obs.observer == "hz"
    assert obs.resource == Resource(topic="/scan")
    assert obs.states == (State(1, "ok"),)
    assert obs.values["period"] == pytest.approx(0.1)
    assert obs.values["period_deviation"] == pytest.approx(0.0, abs=1e-9)
    assert obs.values["rate_hz"] == pytest.approx(10.0)
    assert obs.values["silent_for"] == pytest.approx(0.05)
    assert obs.message == "period 0.1 s (10 Hz) fits 'ok'"


def test_slow_topic_fits_no_state() -> None:
    hz = build()
    feed(hz, ticks(0.0, 0.2, 6))
    [obs] = hz.evaluate(1.1)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.states == ()
    assert obs.values["period"] == pytest.approx(0.2)
    assert obs.message == "period 0.2 s (5 Hz) fits no state (expected 'ok')"


def test_stalled_topic_counts_the_silence_as_a_provisional_period() -> None:
    hz = build()
    feed(hz, ticks(0.0, 0.1, 11))  # last message at 1.0
    [obs] = hz.evaluate(2.0)
    # window of 5: four periods of 0.1 and the provisional 1.0 s -> mean 1.4 / 5
    assert obs.code == Code.NO_STATE_FITS
    assert obs.values["period"] == pytest.approx(0.28)
    assert obs.values["silent_for"] == pytest.approx(1.0)
    assert "no message for 1 s (counted as a provisional period)" in obs.message


def test_provisional_period_is_not_kept_in_the_filter() -> None:
    hz = build()
    feed(hz, ticks(0.0, 0.1, 11))
    hz.evaluate(2.0)
    hz.evaluate(2.5)
    feed(hz, [2.0])  # the real period 1.0 s is counted exactly once
    [obs] = hz.evaluate(2.05)
    assert obs.values["period"] == pytest.approx((4 * 0.1 + 1.0) / 5)
    feed(hz, ticks(2.1, 0.1, 5))
    [obs] = hz.evaluate(2.55)
    assert obs.code == Code.GENERAL_OK
    assert obs.values["period"] == pytest.approx(0.1)


def test_silence_shorter_than_the_period_changes_nothing() -> None:
    hz = build()
    feed(hz, ticks(0.0, 0.1, 11))
    [obs] = hz.evaluate(1.09)
    assert obs.values["period"] == pytest.approx(0.1)
    assert "provisional" not in obs.message


def test_not_available_before_two_messages() -> None:
    hz = build()
    [obs] = hz.evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for first message"
    feed(hz, [1.5])
    [obs] = hz.evaluate(2.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for a second message (one so far, 0.5 s ago)"


def test_publisher_group_counts_only_its_publishers() -> None:
    hz = build("publishers: [/laser_front]")
    for t in ticks(0.0, 0.1, 11):
        hz.on_message(MessageArrival(t, "/scan", "/laser_front", 100))
        hz.on_message(MessageArrival(t + 0.05, "/scan", "/laser_rear", 100))
    [obs] = hz.evaluate(1.02)
    assert obs.resource == Resource(topic="/scan", publishers=("/laser_front",))
    assert obs.values["period"] == pytest.approx(0.1)
    assert obs.code == Code.GENERAL_OK


def test_empty_publisher_group_counts_every_publisher() -> None:
    hz = build("publishers: []")
    for t in ticks(0.0, 0.1, 11):
        hz.on_message(MessageArrival(t, "/scan", "/laser_front", 100))
        hz.on_message(MessageArrival(t + 0.05, "/scan", "/laser_rear", 100))
    [obs] = hz.evaluate(1.07)
    assert obs.values["period"] == pytest.approx(0.05)
    assert obs.code == Code.NO_STATE_FITS


def test_out_of_order_arrival_is_not_a_negative_period() -> None:
    hz = build()
    feed(hz, [0.0, 0.1, 0.2, 0.15, 0.3])
    [obs] = hz.evaluate(0.35)
    assert obs.values["period"] == pytest.approx(0.1)


def test_without_states_reports_values_as_ok() -> None:
    hz = OBSERVERS["hz"].build(ConfigNode.parse("type: hz\ntopic: /scan\nevery: 0.5\n", "t.yaml"))
    assert hz.interval == 0.5
    feed(hz, [0.0, 0.25, 0.5])
    [obs] = hz.evaluate(0.6)
    assert obs.code == Code.GENERAL_OK
    assert obs.values["period"] == pytest.approx(0.25)  # nofilter: the latest period
    assert obs.message == "period 0.25 s (4 Hz) (no states configured)"


def test_interest_and_describe() -> None:
    hz = build("publishers: [/laser]")
    assert hz.interest() == Interest(topics=frozenset({"/scan"}))
    assert hz.describe() == (
        "hz /scan [/laser]: mean (window 5, deviation std_deviation) of period; "
        "state 1 'ok': period: |value - 0.1| < 0.01, every 1 s")


@pytest.mark.parametrize(("extra", "line", "text"), [
    ("publisher: [/a]", 3, "unknown key 'publisher'; did you mean 'publishers'?"),
    ("every: 0", 3, "must be > 0"),
    ("publishers: [/a, /a]", 3, "lists a publisher twice"),
])
def test_config_errors_name_the_line(extra: str, line: int, text: str) -> None:
    with pytest.raises(ConfigError) as err:
        build(extra)
    assert err.value.line == line
    assert text in err.value.message


def test_missing_topic_and_bad_state() -> None:
    with pytest.raises(ConfigError, match="missing required key 'topic'"):
        OBSERVERS["hz"].build(ConfigNode.parse("type: hz\n", "t.yaml"))
    with pytest.raises(ConfigError) as err:
        OBSERVERS["hz"].build(ConfigNode.parse(
            "type: hz\ntopic: /a\nstates:\n  - {number: 1, name: ok, frequency: {}}\n",
            "t.yaml"))
    assert err.value.line == 4
    assert "unknown key 'frequency'" in err.value.message
