"""Alert rules and webhook delivery: the rules file, matching, the persistent outbox.

Real parts only: a real station database, the real alert service thread, a real HTTP
receiver on 127.0.0.1 (one that answers 500 first, one that hangs, one that redirects, one
that is not there until the station restarts). Every wait is on a condition, bounded.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from alert_support import (
    SECRET,
    robot_with_entity,
    rules_file,
    webhook_receiver,
)
from blackbox.cli import main
from blackbox.station.alerts.rules import (
    AlertConfig,
    AlertInput,
    load_alert_config,
    parse_rule_text,
)
from blackbox.station.alerts.service import AlertService
from blackbox.station.store import StationStore
from conftest import wait_for


def config_text(url: str, *, attempts: int = 5, backoff: float = 0.05, extra: str = "",
                timeout: float = 2.0) -> str:
    return f"""\
delivery: {{attempts: {attempts}, backoff: {backoff}, max_backoff: 0.5}}
channels:
  oncall: {{type: webhook, url: "{url}", secret: "{SECRET}", timeout: {timeout}}}
rules:
  - name: camera down
    match: {{robot: "tug-*", entity: /usb_cam, kind: [failure, exceedance]}}
    send: oncall
{extra}"""


@contextmanager
def running(store: StationStore, db: Path, config: AlertConfig) -> Iterator[AlertService]:
    service = AlertService(store, db, config, tick=0.1)
    service.start()
    try:
        yield service
    finally:
        service.stop()


@pytest.fixture
def store(tmp_path: Path) -> Iterator[StationStore]:
    opened = StationStore.open(tmp_path / "station.db")
    yield opened
    opened.close()


def fail(store: StationStore, rid: int, n: int = 1, entity: str = "/usb_cam") -> None:
    store.add_event(rid, time.time(), "failure", dedup=f"f{n}|{entity}", entity=entity,
                    text=f"{entity} stopped publishing")
    assert store.flush(force=True)


# ---- the rules file ---------------------------------------------------------------------


@pytest.mark.parametrize(("body", "where", "message"), [
    ("channels: {}\nrules:\n  - name: x\n    send: pager\n", ":4:11: at rules[0].send",
     "unknown channel 'pager'"),
    ("channels:\n  a: {type: webhook, url: 'ftp://x', secret: '0123456789abcdef'}\n",
     ":2:27: at channels.a.url", "starts with http:// or https://"),
    ("channels:\n  a: {type: webhook, url: 'http://127.0.0.1/', secret: short}\n",
     "at channels.a.secret", "at least 16 characters"),
    ("rules:\n  - name: x\n    send: a\n    match: {kind: failures}\n", "at rules[0].send",
     "unknown channel"),
    ("channels:\n  a: {type: webhook, url: 'http://127.0.0.1/', secret: '0123456789abcdef'}\n"
     "rules:\n  - name: x\n    send: a\n    match: {kind: failures}\n",
     ":6:19: at rules[0].match.kind", "unknown value 'failures'; expected one of"),
    ("channels:\n  a: {type: webhook, url: 'http://127.0.0.1/', secret: '0123456789abcdef'}\n"
     "rules:\n  - name: x\n    send: a\n    escalate: [{after: 60, send: a}, {after: 30, "
     "send: a}]\n", "at rules[0].escalate[1].after", "in order of time"),
    ("channels:\n  m: {type: email, host: 127.0.0.1, from: a@b, to: nobody}\n",
     "at channels.m.to", "e-mail addresses"),
    ("chanels: {}\n", ":1:1: at chanels", "did you mean 'channels'?"),
])
def test_a_bad_rules_file_stops_the_station_naming_file_line_and_key_path(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], body: str, where: str,
        message: str) -> None:
    path = rules_file(tmp_path, body)
    code = main(["station", "--alerts", str(path), "--db", str(tmp_path / "s.db")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.count("\n") == 0, err  # one line, no traceback
    assert str(path) in err and where in err and message in err, err
    assert not (tmp_path / "s.db").exists()  # refused before anything was opened


def test_rules_match_robot_globs_sites_entities_kinds_and_statuses(tmp_path: Path) -> None:
    config = load_alert_config(rules_file(tmp_path, """\
channels:
  a: {type: webhook, url: "http://127.0.0.1:9/", secret: "0123456789abcdef"}
sites:
  depot: ["tug-1", "agv-*"]
"""))
    rule = parse_rule_text("name: r\nsend: a\nmatch: {site: depot, robot: 'tug-*', "
                           "entity: '/cam*', kind: failure, status: NOT_OPERATIONAL}", config)

    def item(robot: str = "tug-1", entity: str = "/camera", kind: str = "failure",
             status: str = "NOT_OPERATIONAL") -> AlertInput:
        return AlertInput(kind, robot, entity, status, "", 0.0)

    assert rule.matches(item())
    assert not rule.matches(item(robot="tug-2"))  # a tug, but not at the depot
    assert not rule.matches(item(robot="agv-1"))  # at the depot, but not a tug
    assert not rule.matches(item(entity="/lidar"))
    assert not rule.matches(item(kind="exceedance"))
    assert not rule.matches(item(status="DEGRADED"))
    everything = parse_rule_text("name: all\nsend: a", config)
    assert all(everything.matches(item(kind=k)) for k in (
        "failure", "exceedance", "diagnosis", "robot_silent", "station_problem"))


# ---- webhook delivery -------------------------------------------------------------------


def test_a_failure_reaches_a_webhook_that_fails_twice_then_recovers_signed(
        tmp_path: Path, store: StationStore) -> None:
    rid = robot_with_entity(store)
    with webhook_receiver(fail_first=2) as hook:
        config = load_alert_config(rules_file(tmp_path, config_text(hook.url)))
        with running(store, tmp_path / "station.db", config) as service:
            fail(store, rid)
            got = hook.wait_for(1, timeout=15)[0]
            assert got.signed_by(SECRET)
            assert not got.signed_by("another secret of 16+ chars")
            body = got.json
            assert body["schema"] == "blackbox.alert/1" and body["type"] == "alert"
            assert body["rule"] == "camera down"
            assert (body["alert"]["robot"], body["alert"]["entity"],
                    body["alert"]["kind"]) == ("tug-1", "/usb_cam", "failure")
            assert hook.attempts == 3
            entry = service.outbox.entries()[0]
            assert wait_for(lambda: service.outbox.entries()[0].state == "sent", 5)
            entry = service.outbox.entries()[0]
            assert (entry.attempts, got.headers["X-Blackbox-Delivery"]) == (3, str(entry.id))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_outbox_survives_a_station_restart(tmp_path: Path, store: StationStore) -> None:
    rid = robot_with_entity(store)
    port = _free_port()
    url = f"http://127.0.0.1:{port}/hook"
    config = load_alert_config(rules_file(tmp_path, config_text(url, attempts=50,
                                                                backoff=0.2)))
    with running(store, tmp_path / "station.db", config) as service:
        fail(store, rid)
        assert wait_for(lambda: any(e.attempts >= 2 for e in service.outbox.entries()), 10), \
            "waited for two refused attempts"
        assert service.outbox.entries()[0].state == "pending"
        assert "cannot connect" in service.outbox.entries()[0].last_error
    with webhook_receiver(port=port) as hook, \
            running(store, tmp_path / "station.db", config) as service:
        got = hook.wait_for(1, timeout=15)
        assert [r.json["type"] for r in got] == ["alert"]
        assert wait_for(lambda: service.outbox.entries()[0].state == "sent", 5)
        assert len(service.engine.alerts()) == 1  # the event was not alerted twice


@pytest.mark.parametrize(("mode", "error"), [
    ("fail", "HTTP 500"), ("hang", "no answer within 0.3 s"),
    ("redirect", "HTTP 307 redirect to http://127.0.0.1:9/elsewhere not followed")])
def test_a_webhook_that_fails_for_good_is_a_visible_problem(
        tmp_path: Path, store: StationStore, mode: str, error: str) -> None:
    rid = robot_with_entity(store)
    with webhook_receiver(fail_first=100 if mode == "fail" else 0,
                          mode="ok" if mode == "fail" else mode) as hook:
        config = load_alert_config(rules_file(tmp_path, config_text(
            hook.url, attempts=2, timeout=0.3)))
        with running(store, tmp_path / "station.db", config) as service:
            fail(store, rid)
            assert wait_for(lambda: any(e.state == "failed"
                                        for e in service.outbox.entries()), 15), \
                "waited for the notification to fail for good"
            entry = service.outbox.entries()[0]
            assert entry.attempts == 2 and error in entry.last_error

            def shown() -> list[str]:  # reported just after the row is marked failed
                return [p.message for p in store.problems() if p.source == "alerts"
                        and "failed after 2 attempts" in p.message and error in p.message]
            assert wait_for(lambda: bool(shown()), 5), store.problems()
        assert hook.attempts == 2


def test_events_no_rule_matches_are_counted_not_swallowed(tmp_path: Path,
                                                          store: StationStore) -> None:
    rid = robot_with_entity(store)
    with webhook_receiver() as hook:
        config = load_alert_config(rules_file(tmp_path, config_text(hook.url)))
        with running(store, tmp_path / "station.db", config) as service:
            for n in range(3):
                fail(store, rid, n, entity="/lidar")  # the rule wants /usb_cam
            fail(store, rid, 9)
            hook.wait_for(1, timeout=10)
            assert wait_for(lambda: service.engine.unmatched(time.time() - 3600)
                            == {"failure": 3}, 5), service.engine.unmatched(0)
