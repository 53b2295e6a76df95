"""timing observer: delay from a message on topic A to the next one on topic B."""

from __future__ import annotations

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS

CONFIG = """\
type: timing
topic_a: /goal
topic_b: /result
{extra}
filter: {{type: mean, window_size: 3}}
states:
  - number: 1
    name: in_time
    delay: {{value: {{type: in_between, lower_bound: 1.0, upper_bound: 3.0}}}}
"""


def build(extra: str = ""):
    return OBSERVERS["timing"].build(ConfigNode.parse(CONFIG.format(extra=extra), "t.yaml"))


def feed(observer, events):
    for t, topic, *publisher in events:
        observer.on_message(MessageArrival(t, topic, publisher[0] if publisher else "/nav", 10))


SEQUENCE = [(0.0, "/goal"), (2.0, "/result"), (10.0, "/goal"), (11.5, "/result"),
            (12.0, "/result")]


def test_every_b_counts_its_delay_from_the_latest_a() -> None:
    tm = build()
    feed(tm, SEQUENCE)
    [obs] = tm.evaluate(13.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.states == (State(1, "in_time"),)
    assert obs.resource == Resource(topic="/goal", topic_b="/result")
    assert obs.values["delay"] == pytest.approx((2.0 + 1.5 + 2.0) / 3)
    assert "waiting_for" not in obs.values
    assert obs.message == "delay 1.833 s fits 'in_time'"


def test_single_shot_counts_only_the_first_b_after_each_a() -> None:
    tm = build("single_shot: true")
    feed(tm, SEQUENCE)
    [obs] = tm.evaluate(13.0)
    assert obs.values["delay"] == pytest.approx((2.0 + 1.5) / 2)


def test_several_a_before_b_count_from_the_latest() -> None:
    tm = build()
    feed(tm, [(0.0, "/goal"), (1.0, "/goal"), (1.2, "/result")])
    [obs] = tm.evaluate(2.0)
    assert obs.values["delay"] == pytest.approx(0.2)
    assert obs.code == Code.NO_STATE_FITS


def test_b_without_a_is_ignored() -> None:
    tm = build()
    feed(tm, [(0.0, "/result")])
    [obs] = tm.evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for a message on /goal"
    feed(tm, [(1.5, "/goal")])
    [obs] = tm.evaluate(2.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for a message on /result after the one on /goal 0.5 s ago"


def test_a_b_that_never_comes_shows_as_a_provisional_delay() -> None:
    tm = build()
    feed(tm, SEQUENCE)
    feed(tm, [(20.0, "/goal")])
    [obs] = tm.evaluate(21.5)  # waiting 1.5 s, shorter than the filtered 1.83 s
    assert obs.values["waiting_for"] == pytest.approx(1.5)
    assert obs.values["delay"] == pytest.approx((2.0 + 1.5 + 2.0) / 3)
    assert obs.code == Code.GENERAL_OK
    [obs] = tm.evaluate(30.0)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.values["delay"] == pytest.approx((1.5 + 2.0 + 10.0) / 3)
    assert obs.message.endswith(
        "no message on /result for 10 s since /goal (counted as a provisional delay)")
    feed(tm, [(30.5, "/result")])
    [obs] = tm.evaluate(31.0)
    assert obs.values["delay"] == pytest.approx((1.5 + 2.0 + 10.5) / 3)


def test_publisher_groups_on_both_sides() -> None:
    tm = build("publishers_a: [/planner]\npublishers_b: [/controller]")
    assert tm.resource == Resource(topic="/goal", publishers=("/planner",), topic_b="/result")
    feed(tm, [(0.0, "/goal", "/planner"), (0.5, "/goal", "/teleop"),
              (1.0, "/result", "/logger"), (2.0, "/result", "/controller")])
    [obs] = tm.evaluate(3.0)
    assert obs.values["delay"] == pytest.approx(2.0)


def test_same_topic_both_ends() -> None:
    tm = OBSERVERS["timing"].build(ConfigNode.parse(
        "type: timing\ntopic_a: /beat\ntopic_b: /beat\n", "t.yaml"))
    feed(tm, [(0.0, "/beat"), (0.4, "/beat"), (1.0, "/beat")])
    [obs] = tm.evaluate(1.0)
    assert obs.values["delay"] == pytest.approx(0.6)


def test_interest_and_describe() -> None:
    tm = build("single_shot: true\npublishers_b: [/controller]")
    assert tm.interest() == Interest(topics=frozenset({"/goal", "/result"}))
    assert tm.describe().startswith(
        "timing /goal [all publishers] -> /result [/controller], single shot: mean (window 3")


@pytest.mark.parametrize(("extra", "line", "message"), [
    ("single_shot: yes please", 4, "expected true or false"),
    ("topic_c: /x", 4, "unknown key 'topic_c'"),
    ("publishers_a: 5", 4, "expected a list"),
])
def test_config_errors(extra: str, line: int, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        build(extra)
    assert err.value.line == line
    assert message in err.value.message


def test_missing_topic_b() -> None:
    with pytest.raises(ConfigError, match="missing required key 'topic_b'"):
        OBSERVERS["timing"].build(ConfigNode.parse("type: timing\ntopic_a: /a\n", "t.yaml"))
