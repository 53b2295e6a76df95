"""timeout observer: TIMEOUT within timeout + 0.25 s of a publisher group's last message."""

from __future__ import annotations

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Resource
from blackbox.observe.base import OBSERVERS


def build(extra: str = "", timeout: str = "timeout: 1.0"):
    text = f"type: timeout\ntopic: /odom\n{timeout}\n{extra}\n"
    return OBSERVERS["timeout"].build(ConfigNode.parse(text, "t.yaml"))


def run(observer, messages, until: float, publisher: str = "/base"):
    """Feed ``messages`` (times) and evaluate every ``interval`` up to ``until``."""
    pending = sorted(messages)
    out = []
    steps = round(until / observer.interval)
    for k in range(1, steps + 1):
        now = k * observer.interval
        while pending and pending[0] <= now:
            observer.on_message(MessageArrival(pending.pop(0), "/odom", publisher, 10))
        out.extend(observer.evaluate(now))
    return out


def test_steady_topic_is_ok_once_per_every() -> None:
    to = build()
    assert to.interval == 0.25
    out = run(to, [i * 0.1 for i in range(31)], until=3.0)
    assert [o.time for o in out] == [0.25, 1.25, 2.25]
    assert all(o.code == Code.GENERAL_OK for o in out)
    assert out[0].resource == Resource(topic="/odom")
    assert out[0].observer == "timeout"
    assert out[1].message == "last message 0.05 s ago (timeout 1 s)"


def test_stopped_topic_times_out_within_a_quarter_second() -> None:
    to = build()
    out = run(to, [i * 0.1 for i in range(11)], until=4.0)  # last message at 1.0
    first = next(o for o in out if o.code == Code.TIMEOUT)
    assert first.time == 2.25  # silent 1.25 s > 1 s; at 2.0 it was exactly 1 s
    assert first.values == {"silent_for": pytest.approx(1.25), "timeouts_in_a_row": 1.0}
    assert first.message == ("no message for 1.25 s (timeout 1 s, 1 in a row = "
                             "max_timeouts_in_a_row: considered stopped)")
    assert [(o.time, o.code) for o in out if o.time > 2.25] == [(3.25, Code.TIMEOUT)]


def test_topic_that_never_appears_times_out_from_the_first_evaluation() -> None:
    to = build()
    out = run(to, [], until=2.0)
    assert [(o.time, o.code) for o in out] == [
        (0.25, Code.GENERAL_OK), (1.25, Code.GENERAL_OK), (1.5, Code.TIMEOUT)]
    assert out[2].message.startswith("no message since observation began 1.25 s ago")


def test_consecutive_timeouts_are_counted_up_to_the_maximum() -> None:
    to = build("max_timeouts_in_a_row: 3", timeout="timeout: 0.5")
    assert to.interval == 0.125
    to.on_message(MessageArrival(0.0, "/odom", "/base", 10))
    [obs] = to.evaluate(0.125)
    assert obs.code == Code.GENERAL_OK
    [obs] = to.evaluate(1.25)
    assert obs.code == Code.TIMEOUT
    assert obs.values["timeouts_in_a_row"] == 2.0
    assert obs.message == "no message for 1.25 s (timeout 0.5 s, 2 in a row)"
    [obs] = to.evaluate(2.25)
    assert obs.code == Code.TIMEOUT
    assert obs.values["timeouts_in_a_row"] == 3.0  # 4 whole timeouts, counted up to 3
    assert obs.message.endswith("3 in a row = max_timeouts_in_a_row: considered stopped)")


def test_recovery_is_reported_at_once() -> None:
    to = build()
    to.on_message(MessageArrival(0.0, "/odom", "/base", 10))
    assert to.evaluate(0.25)[0].code == Code.GENERAL_OK
    assert to.evaluate(1.5)[0].code == Code.TIMEOUT
    assert to.evaluate(1.75) == []  # same code, not yet due
    to.on_message(MessageArrival(1.8, "/odom", "/base", 10))
    [obs] = to.evaluate(2.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.values["silent_for"] == pytest.approx(0.2)


def test_publisher_group_times_out_while_others_publish() -> None:
    to = build("publishers: [/front]")
    assert to.resource == Resource(topic="/odom", publishers=("/front",))
    to.on_message(MessageArrival(0.0, "/odom", "/front", 10))
    for k in range(1, 20):
        to.on_message(MessageArrival(k * 0.1, "/odom", "/rear", 10))
    [obs] = to.evaluate(1.9)
    assert obs.code == Code.TIMEOUT
    assert obs.values["silent_for"] == pytest.approx(1.9)


def test_any_publisher_keeps_an_empty_group_alive() -> None:
    to = build()
    to.on_message(MessageArrival(0.0, "/odom", "/front", 10))
    to.on_message(MessageArrival(1.5, "/odom", "/rear", 10))
    [obs] = to.evaluate(1.9)
    assert obs.code == Code.GENERAL_OK


@pytest.mark.parametrize(("every", "timeout", "interval"), [
    (1.0, 10.0, 0.25), (1.0, 0.2, 0.05), (0.1, 10.0, 0.1), (1.0, 0.001, 0.01)])
def test_evaluation_interval(every: float, timeout: float, interval: float) -> None:
    to = build(f"every: {every}", timeout=f"timeout: {timeout}")
    assert to.interval == pytest.approx(interval)


def test_interest_and_describe() -> None:
    to = build("max_timeouts_in_a_row: 5")
    assert to.interest() == Interest(topics=frozenset({"/odom"}))
    assert to.describe() == ("timeout /odom [all publishers]: no message for 1 s, max 5 in a "
                             "row, checked every 0.25 s, reported every 1 s")


@pytest.mark.parametrize(("timeout", "extra", "line", "text"), [
    ("", "", 1, "missing required key 'timeout'"),
    ("timeout: -1", "", 3, "must be > 0"),
    ("timeout: 0", "", 3, "must be > 0"),
    ("timeout: soon", "", 3, "expected a number"),
    ("timeout: 1", "max_timeouts_in_a_row: 0", 4, "must be >= 1"),
    ("timeout: 1", "filter: {type: mean, window_size: 3}", 4, "unknown key 'filter'"),
])
def test_config_errors(timeout: str, extra: str, line: int, text: str) -> None:
    with pytest.raises(ConfigError) as err:
        build(extra, timeout=timeout)
    assert err.value.line == line
    assert text in err.value.message
