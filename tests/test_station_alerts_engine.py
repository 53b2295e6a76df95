"""The alert engine's rules over time: dedup, rate limit with a digest, ``lasting``,
escalation stopped by acknowledgement, resolution, and the audit of every step.

A real station database and the real engine; time is passed in, so an escalation after
five minutes is checked without waiting five minutes. What would be sent is read from the
outbox (the delivery itself is tested in test_station_alerts.py).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from alert_support import robot_with_entity, rules_file
from blackbox.station.alerts.channels import Outcome
from blackbox.station.alerts.db import AlertDB
from blackbox.station.alerts.engine import AlertEngine, AlertRuleError
from blackbox.station.alerts.outbox import Outbox
from blackbox.station.alerts.rules import load_alert_config
from blackbox.station.store import StationStore

CHANNELS = """\
channels:
  hook: {type: webhook, url: "http://127.0.0.1:9/", secret: "0123456789abcdef"}
  pager: {type: webhook, url: "http://127.0.0.1:9/p", secret: "0123456789abcdef"}
  boss: {type: webhook, url: "http://127.0.0.1:9/b", secret: "0123456789abcdef"}
"""


class World:
    def __init__(self, tmp: Path, rules: str) -> None:
        self.store = StationStore.open(tmp / "station.db")
        self.rid = robot_with_entity(self.store)
        self.db = AlertDB(tmp / "station.db")
        config = load_alert_config(rules_file(tmp, CHANNELS + rules))
        self.audited: list[tuple[str, str, str, str]] = []
        self.engine = AlertEngine(self.store, self.db, config, Outbox(self.db, config.delivery),
                                  lambda u, a, t, o, d: self.audited.append((u, a, t, o)))
        self.n = 0
        self.t0 = time.time()

    def event(self, kind: str, entity: str = "/usb_cam", at: float = 0.0) -> None:
        self.n += 1
        self.store.add_event(self.rid, self.t0 + at, kind, dedup=f"{kind}{self.n}",
                             entity=entity, text=f"{entity} {kind} #{self.n}")
        assert self.store.flush(force=True)
        self.engine.poll(self.t0 + at)

    def sent(self) -> list[tuple[str, str]]:
        """(purpose, channel) of the outbox, oldest first."""
        return [(e.purpose, e.channel) for e in reversed(self.engine.outbox.entries())]

    def close(self) -> None:
        self.db.close()
        self.store.close()


@pytest.fixture
def world(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[World]:
    w = World(tmp_path, request.param)
    yield w
    w.close()


ESCALATING = """\
rules:
  - name: camera
    match: {entity: /usb_cam, kind: failure}
    send: hook
    escalate:
      - {after: 300, send: pager}
      - {after: 900, send: boss}
"""


@pytest.mark.parametrize("world", [ESCALATING], indirect=True)
def test_an_unacknowledged_alert_escalates_step_by_step(world: World) -> None:
    world.event("failure")
    world.engine.tick(world.t0 + 299)
    assert world.sent() == [("alert", "hook")]
    world.engine.tick(world.t0 + 301)
    assert world.sent()[-1] == ("escalation", "pager")
    world.engine.tick(world.t0 + 301)  # once per step
    world.engine.tick(world.t0 + 901)
    assert world.sent() == [("alert", "hook"), ("escalation", "pager"),
                            ("escalation", "boss")]
    world.event("rectification", at=1000)
    assert world.sent()[3:] == [("resolved", "hook"), ("resolved", "pager"),
                                ("resolved", "boss")]
    actions = [a[1] for a in world.audited]
    assert actions == ["alert.fire", "alert.escalate", "alert.escalate", "alert.resolve"]


@pytest.mark.parametrize("world", [ESCALATING], indirect=True)
def test_acknowledging_stops_escalation_in_the_page_or_through_the_event(
        world: World) -> None:
    world.event("failure")
    alert = world.engine.alerts()[0]
    world.engine.acknowledge(alert.id, "otto", world.t0 + 10)
    world.engine.tick(world.t0 + 2000)
    assert world.sent() == [("alert", "hook")]
    assert world.engine.alert(alert.id).state == "acknowledged"  # type: ignore[union-attr]
    # acknowledging the failure event itself (the events page, the API) acks its alert
    world.event("failure", entity="/usb_cam", at=3000)  # same key: still the same alert
    world.event("rectification", at=3001)
    world.event("failure", at=3002)
    second = world.engine.alerts()[0]
    assert second.id != alert.id and second.state == "firing"
    world.store.acknowledge(int(second.event_id or 0), "ada")
    world.engine.poll(world.t0 + 3003)
    assert world.engine.alert(second.id).acked_by == "ada"  # type: ignore[union-attr]
    assert ("ada", "alert.ack", f"alert {second.id} tug-1:/usb_cam:failure", "ok") \
        in world.audited


@pytest.mark.parametrize("world", ["""\
rules:
  - name: flapping
    match: {kind: [failure, exceedance]}
    send: hook
    rate_limit: {count: 3, per: 600}
"""], indirect=True)
def test_a_flapping_sensor_is_rate_limited_and_the_rest_sent_as_one_digest(
        world: World) -> None:
    for i in range(50):  # fails and recovers 50 times within ten minutes
        world.event("failure", at=i * 2)
        world.event("rectification", at=i * 2 + 1)
    alerts = [p for p, _ in world.sent() if p == "alert"]
    assert len(alerts) == 3
    resolved = [p for p, _ in world.sent() if p == "resolved"]
    assert len(resolved) == 3  # only what was announced is resolved
    assert [a.notified for a in world.engine.alerts(limit=100)].count(True) == 3
    world.engine.tick(world.t0 + 599)
    assert ("digest", "hook") not in world.sent()
    world.engine.tick(world.t0 + 601)
    digest = [e for e in world.engine.outbox.entries() if e.purpose == "digest"]
    assert len(digest) == 1
    assert digest[0].payload["suppressed"] == 47
    assert "47 more alert(s)" in digest[0].payload["summary"]
    assert len(digest[0].payload["suppressed_examples"]) == 10


@pytest.mark.parametrize("world", ["""\
rules:
  - name: dedup
    match: {kind: failure}
    send: hook
"""], indirect=True)
def test_repeats_of_an_open_alert_count_up_instead_of_sending_again(world: World) -> None:
    for i in range(20):
        world.event("failure", at=i)
    assert world.sent() == [("alert", "hook")]
    assert world.engine.alerts()[0].count == 20


@pytest.mark.parametrize("world", ["""\
rules:
  - name: lasting
    match: {kind: failure, lasting: 60}
    send: hook
"""], indirect=True)
def test_a_condition_must_last_before_it_alerts(world: World) -> None:
    world.event("failure")
    world.event("rectification", at=30)
    world.engine.tick(world.t0 + 100)
    assert world.sent() == []  # it did not last: nobody woken
    world.event("failure", at=200)
    world.engine.tick(world.t0 + 259)
    assert world.sent() == []
    world.engine.tick(world.t0 + 261)
    assert world.sent() == [("alert", "hook")]


@pytest.mark.parametrize("world", ["rules: []\n"], indirect=True)
def test_page_rules_are_checked_like_the_file_and_tested_on_demand(world: World) -> None:
    with pytest.raises(AlertRuleError, match=r"<rule>:2:7: at send: unknown channel 'nope'"):
        world.engine.add_rule("name: x\nsend: nope\n", "ada", world.t0)
    world.engine.add_rule("name: silent robots\nsend: [hook, pager]\n"
                          "match: {kind: robot_silent}\n", "ada", world.t0)
    with pytest.raises(AlertRuleError, match="exists already"):
        world.engine.add_rule("name: silent robots\nsend: hook\n", "ada", world.t0)
    ids = world.engine.send_test("silent robots", "ada", world.t0)
    assert len(ids) == 2 and world.sent() == [("test", "hook"), ("test", "pager")]
    world.engine.remove_rule("silent robots", "ada")
    assert world.engine.rules == ()
    assert [(a[1], a[3]) for a in world.audited] == [
        ("alert.rule.add", "refused"), ("alert.rule.add", "ok"), ("alert.rule.add", "refused"),
        ("alert.test", "ok"), ("alert.rule.remove", "ok")]


@pytest.mark.parametrize("world", ["""\
rules:
  - name: silence
    match: {kind: robot_silent}
    send: hook
"""], indirect=True)
def test_a_robot_that_goes_silent_alerts_and_recovers(world: World) -> None:
    heard = world.store.last_heard("tug-1") or world.t0
    world.engine.tick(heard + 1)
    assert world.sent() == []
    world.engine.tick(heard + world.store.stale_after + 1)
    assert world.sent() == [("alert", "hook")]
    assert world.engine.alerts()[0].kind == "robot_silent"
    world.store.heard(world.rid, heard + 100)
    assert world.store.flush(force=True)
    world.engine.tick(heard + 100.5)
    assert world.sent() == [("alert", "hook"), ("resolved", "hook")]


@pytest.mark.parametrize("world", ["""\
rules:
  - name: everything
    send: hook
"""], indirect=True)
def test_a_rule_matching_everything_sends_at_most_its_limit_then_a_digest(
        world: World) -> None:
    for i in range(200):  # 200 different entities failing: 200 distinct alerts
        world.event("failure", entity=f"/node_{i}", at=i * 0.1)
    assert len(world.engine.alerts(limit=1000)) == 200
    assert world.sent() == [("alert", "hook")] * 10  # the default limit: 10 per 600 s
    world.engine.tick(world.t0 + 601)
    digest = [e for e in world.engine.outbox.entries() if e.purpose == "digest"]
    assert [d.payload["suppressed"] for d in digest] == [190]
    assert world.engine.unmatched(0) == {}  # matched, so not counted as unmatched


@pytest.mark.parametrize("world", ["""\
rules:
  - name: thresholds
    match: {kind: exceedance}
    send: hook
"""], indirect=True)
def test_an_exceedance_is_resolved_when_the_entity_is_healthy_again(world: World) -> None:
    world.event("exceedance")
    world.event("exceedance", at=1)  # the same alert, counted
    world.event("state_change", at=2)  # between healthy states: over
    world.event("exceedance", at=3)  # a new one
    assert world.sent() == [("alert", "hook"), ("resolved", "hook"), ("alert", "hook")]
    assert [a.count for a in world.engine.alerts()] == [1, 2]


@pytest.mark.parametrize("world", ["""\
rules:
  - name: dedup
    match: {kind: failure}
    send: hook
"""], indirect=True)
def test_history_older_than_thirty_days_is_pruned_but_failures_stay(world: World) -> None:
    world.event("failure")
    world.event("rectification", at=1)
    outbox = world.engine.outbox
    first, second = (e.id for e in reversed(outbox.entries()))
    outbox.record(first, Outcome(True, "HTTP 204"), world.t0 + 2)
    for _ in range(world.engine.outbox.delivery.attempts):
        outbox.record(second, Outcome(False, "HTTP 500"), world.t0 + 2)
    assert world.engine.prune(world.t0 + 29 * 86400) == 0
    assert world.engine.prune(world.t0 + 31 * 86400) == 2  # the alert and the sent row
    assert world.engine.alerts() == []
    assert [e.state for e in outbox.entries()] == ["failed"]
