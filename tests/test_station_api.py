"""``/api/v1`` and ``/metrics``: a contract test walking the OpenAPI document, tokens
(hashed, role-scoped, expiring, revocable), bad requests, and both metrics endpoints
scraped (the station's in-process, the robot's from a real ``blackbox run --metrics``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from alert_support import robot_with_entity, rules_file
from blackbox.station.alerts.rules import load_alert_config
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Role
from blackbox.station.store import StationStore
from blackbox.station.tokens import ApiTokens
from blackbox.station.web.app import create_app
from station_support import quick_auth

PASSWORD = "station password 1"


class StoreOperations:
    """Operations that only record the request in the station database (no robot)."""

    def __init__(self, store: StationStore) -> None:
        self.store = store

    def request_logs(self, robot: str | int, *, entity: str | None = None,
                     characteristic: str | None = None, since: float | None = None,
                     until: float | None = None, kinds: Sequence[str] = (),
                     requested_by: str = "") -> int:
        rid = self.store.resource_of(robot)
        return self.store.create_log_request(rid, str(robot), entity=entity,
                                             characteristic=None, since=since, until=until,
                                             kinds=kinds, requested_by=requested_by)

    def run_ibit(self, robot: str | int, entity: str = "", requested_by: str = "") -> int:
        rid = self.store.resource_of(robot)
        return self.store.create_ibit_run(rid, str(robot), entity, requested_by)


class Station:
    def __init__(self, tmp: Path) -> None:
        path = tmp / "station.db"
        self.store = StationStore.open(path)
        self.auth = quick_auth(path)
        self.tokens = ApiTokens(path, self.auth)
        self.token: dict[str, str] = {}
        for name, role in (("vera", Role.VIEWER), ("otto", Role.OPERATOR),
                           ("ada", Role.ADMIN)):
            self.auth.add_user(name, PASSWORD, role)
            self.token[name] = self.tokens.create(name, "test", 1)[0]
        self.rid = robot_with_entity(self.store)
        config = load_alert_config(rules_file(tmp, """\
channels:
  hook: {type: webhook, url: "http://127.0.0.1:9/", secret: "0123456789abcdef"}
rules:
  - {name: cameras, match: {entity: /usb_cam}, send: hook}
"""))
        self.alerts = AlertService(self.store, path, config, audit=lambda u, a, t, o, d: (
            self.auth.audit(u, a, t, o, "station", d)))
        self.store.add_event(self.rid, time.time(), "failure", dedup="f1", entity="/usb_cam",
                             text="/usb_cam stopped")
        assert self.store.flush(force=True)
        self.alerts.engine.poll(time.time())
        app = create_app(self.auth, self.store, StoreOperations(self.store),
                         alerts=self.alerts, metrics_token="scrape token 123")
        self.client = TestClient(app, base_url="http://127.0.0.1")

    def as_(self, name: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token[name]}"}


@pytest.fixture
def station(tmp_path: Path) -> Iterator[Station]:
    s = Station(tmp_path)
    with s.client:
        yield s
    s.alerts.stop()
    s.tokens.close()
    s.auth.close()
    s.store.close()


def resolve(doc: dict[str, Any], schema: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[1]
        schema = doc["components"]["schemas"][name]
    return schema


def conforms(doc: dict[str, Any], schema: dict[str, Any], value: Any, where: str) -> None:
    """A small structural check: types, required properties, array items (recursively)."""
    schema = resolve(doc, schema)
    options = schema.get("anyOf") or schema.get("oneOf")
    if options:
        errors = []
        for option in options:
            try:
                conforms(doc, option, value, where)
                return
            except AssertionError as exc:
                errors.append(str(exc))
        raise AssertionError(f"{where}: matches none of {errors}")
    kind = schema.get("type")
    types = {"object": dict, "array": list, "string": str, "boolean": bool,
             "integer": int, "number": (int, float), "null": type(None)}
    if kind is not None:
        assert isinstance(value, types[kind]), f"{where}: {value!r} is not {kind}"
    if kind == "object":
        for key in schema.get("required", []):
            assert key in value, f"{where}: missing {key!r}"
        for key, sub in schema.get("properties", {}).items():
            if key in value:
                conforms(doc, sub, value[key], f"{where}.{key}")
    if kind == "array":
        for i, item in enumerate(value):
            conforms(doc, schema.get("items", {}), item, f"{where}[{i}]")


def test_every_operation_of_the_openapi_document_answers_as_documented(
        station: Station) -> None:
    doc = station.client.get("/api/v1/openapi.json").json()
    assert doc["info"]["version"] == "1"
    event_id = station.store.events("tug-1").events[0].id
    alert_id = station.alerts.engine.alerts()[0].id
    values = {"robot": "tug-1", "event_id": str(event_id), "alert_id": str(alert_id),
              "number": "1", "name": "cameras"}
    bodies = {("post", "/events/{event_id}/ack"): {"note": "seen"},
              ("post", "/alerts/{alert_id}/ack"): {},
              ("post", "/logs"): {"robot": "tug-1", "entity": "/usb_cam"},
              ("post", "/ibit"): {"robot": "tug-1"},
              ("post", "/alerts/rules"): {"yaml": "name: extra\nsend: hook\n"}}
    order = ["post", "get", "delete"]  # create first, so reads find something
    walked = []
    for method in order:
        for path, item in doc["paths"].items():
            if method not in item:
                continue
            op = item[method]
            url = "/api/v1" + re.sub(r"\{(\w+)\}", lambda m: values[m.group(1)], path)
            if path == "/alerts/rules/{name}" and method == "delete":
                url = "/api/v1/alerts/rules/extra"
            assert station.client.request(method, url, json=bodies.get((method, path))
                                          ).status_code == 401, f"{method} {path} w/o token"
            reply = station.client.request(method, url, headers=station.as_("ada"),
                                           json=bodies.get((method, path)))
            documented = set(op["responses"])
            assert str(reply.status_code) in documented, \
                f"{method} {path}: {reply.status_code} {reply.text[:200]} not in {documented}"
            walked.append((method, path, reply.status_code))
            assert reply.status_code < 300 or reply.status_code == 409, \
                f"{method} {path}: {reply.status_code} {reply.text[:200]}"
            content = op["responses"][str(reply.status_code)].get("content", {})
            schema = content.get("application/json", {}).get("schema")
            if schema and reply.headers["content-type"].startswith("application/json"):
                conforms(doc, schema, reply.json(), f"{method} {path}")
    assert len(walked) == 16, walked
    audit = {(a.user, a.action, a.outcome) for a in station.auth.audit_log(limit=100)}
    assert {("ada", "alarm.ack", "ok"), ("ada", "logs.request", "ok"),
            ("ada", "ibit.run", "ok"), ("ada", "alert.rule.add", "ok")} <= audit


def test_tokens_carry_their_users_role_and_stop_when_revoked_or_expired(
        station: Station) -> None:
    client = station.client
    ack = f"/api/v1/events/{station.store.events('tug-1').events[0].id}/ack"
    assert client.get("/api/v1/fleet", headers=station.as_("vera")).status_code == 200
    refused = client.post(ack, json={}, headers=station.as_("vera"))
    assert refused.status_code == 403 and "operator role" in refused.json()["error"]
    assert client.post("/api/v1/alerts/rules", json={"yaml": "name: x\nsend: hook"},
                       headers=station.as_("otto")).status_code == 403
    assert client.post(ack, json={}, headers=station.as_("otto")).status_code == 200
    # the session cookie is no API credential
    form = client.get("/login").text
    login_token = re.search(r'name="login_token" value="([^"]+)"', form).group(1)  # type: ignore[union-attr]
    client.post("/login", data={"username": "ada", "password": PASSWORD,
                                "login_token": login_token}, follow_redirects=False)
    assert client.get("/api/v1/fleet").status_code == 401
    token_id = int(station.token["otto"].split("_")[1])
    otto = station.auth.user("otto")
    assert otto is not None
    station.tokens.revoke(token_id, otto)
    assert client.get("/api/v1/fleet", headers=station.as_("otto")).status_code == 401
    stored = station.tokens._db.execute("SELECT hash FROM web_api_tokens").fetchall()
    assert all(station.token["otto"].split("_", 2)[2] not in h for (h,) in stored)
    station.tokens._db.execute("UPDATE web_api_tokens SET expires = ? WHERE user = 'vera'",
                               (time.time() - 1,))  # as if its day had passed
    assert client.get("/api/v1/fleet", headers=station.as_("vera")).status_code == 401


def test_oversized_and_malformed_requests_get_clear_errors(station: Station) -> None:
    client = station.client
    headers = station.as_("ada")
    big = client.post("/api/v1/alerts/rules", headers={**headers,
                                                       "Content-Type": "application/json"},
                      content=b'{"yaml": "' + b"x" * 100_000 + b'"}')
    assert big.status_code == 413 and "65536 bytes" in big.text  # the station-wide limit
    bad = client.post("/api/v1/logs", headers={**headers, "Content-Type": "application/json"},
                      content=b"{not json")
    assert bad.status_code == 422 and bad.json()["error"]
    rule = client.post("/api/v1/alerts/rules", headers=headers,
                       json={"yaml": "name: x\nsend: [hook, nope]\n"})
    assert rule.status_code == 400 and "at send[1]: unknown channel 'nope'" in \
        rule.json()["error"]
    assert client.get("/api/v1/robots/nobody", headers=headers).status_code == 404
    kind = client.get("/api/v1/events?kind=nonsense", headers=headers)
    assert kind.status_code == 400 and "unknown event kind" in kind.json()["error"]


def parse_metrics(text: str) -> dict[str, float]:
    values = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            values[name] = float(value)
    return values


def test_the_station_metrics_are_prometheus_text_behind_the_token(station: Station) -> None:
    client = station.client
    assert client.get("/metrics").status_code == 401
    reply = client.get("/metrics", headers={"Authorization": "Bearer scrape token 123"})
    assert reply.status_code == 200
    assert reply.headers["content-type"].startswith("text/plain; version=0.0.4")
    values = parse_metrics(reply.text)
    assert values['blackbox_station_robots{status="OPERATIONAL"}'] == 1
    assert values['blackbox_station_events_total{kind="failure"}'] == 1
    assert values['blackbox_station_alerts{state="firing"}'] == 1
    assert values['blackbox_station_notifications_total{channel="hook",outcome="pending"}'] \
        == 1
    assert values["blackbox_station_database_bytes"] > 0
    for line in reply.text.splitlines():
        if line.startswith("# TYPE"):
            _, _, name, kind = line.split()
            assert re.fullmatch(r"blackbox_station_[a-z_]+", name)
            assert name.endswith("_total") == (kind == "counter"), line


@pytest.mark.slow
def test_blackbox_run_serves_its_own_metrics(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "blackbox", "run", "--quiet",
                             "--duration", "60", "--metrics", "127.0.0.1:0",
                             "--record", str(tmp_path / "health.db")],
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stderr is not None
        url = ""
        deadline = time.monotonic() + 60
        while not url and time.monotonic() < deadline:
            line = proc.stderr.readline()
            assert line, "blackbox run ended before serving metrics"
            found = re.search(r"metrics at (http://\S+)", line)
            url = found.group(1) if found else ""
        assert url, "waited 60 s for the metrics address"
        values: dict[str, float] = {}
        while time.monotonic() < deadline:
            with urllib.request.urlopen(url, timeout=5) as reply:
                values = parse_metrics(reply.read().decode())
            if values.get("blackbox_messages_received_total", 0) > 0 and \
                    values.get('blackbox_observers{state="ok"}', 0) > 0:
                break
            time.sleep(0.2)
        assert values.get("blackbox_messages_received_total", 0) > 0, values
        assert 'blackbox_observers{state="faulty"}' in values
        assert "blackbox_recorder_queued_rows" in values
        assert values["blackbox_recorder_dropped_rows_total"] == 0
        json.dumps(values)
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_the_acknowledge_link_of_a_message_needs_a_log_in_and_the_operator_role(
        station: Station) -> None:
    client = station.client
    alert_id = station.alerts.engine.alerts()[0].id
    reply = client.get(f"/alerts/{alert_id}", follow_redirects=False)
    assert reply.status_code == 303
    assert reply.headers["location"] == f"/login?next=%2Falerts%2F{alert_id}"
    form = client.get("/login").text
    login_token = re.search(r'name="login_token" value="([^"]+)"', form).group(1)  # type: ignore[union-attr]
    client.post("/login", data={"username": "vera", "password": PASSWORD,
                                "login_token": login_token, "next": f"/alerts/{alert_id}"})
    page = client.get(f"/alerts/{alert_id}")
    assert page.status_code == 200 and "/usb_cam stopped" in page.text
    assert "Acknowledge</button>" not in page.text  # a viewer is not offered it ...
    csrf = re.search(r'data-csrf="([^"]+)"', page.text).group(1)  # type: ignore[union-attr]
    refused = client.post(f"/alerts/{alert_id}/ack", data={"csrf_token": csrf})
    assert refused.status_code == 403  # ... nor allowed it
    assert station.alerts.engine.alert(alert_id).state == "firing"  # type: ignore[union-attr]


def test_a_token_made_in_the_page_works_until_it_is_revoked_in_the_page(
        station: Station) -> None:
    client = station.client
    form = client.get("/login").text
    login_token = re.search(r'name="login_token" value="([^"]+)"', form).group(1)  # type: ignore[union-attr]
    client.post("/login", data={"username": "otto", "password": PASSWORD,
                                "login_token": login_token})
    page = client.get("/tokens")
    csrf = re.search(r'data-csrf="([^"]+)"', page.text).group(1)  # type: ignore[union-attr]
    assert client.post("/tokens", data={"op": "create", "name": "grafana", "days": "9999",
                                        "csrf_token": csrf}).status_code == 400
    made = client.post("/tokens", data={"op": "create", "name": "grafana", "days": "30",
                                        "csrf_token": csrf})
    token = re.search(r"<code>(bbt_[^<]+)</code>", made.text).group(1)  # type: ignore[union-attr]
    assert token not in client.get("/tokens").text  # shown once
    client.cookies.clear()  # the API is used without the session
    bearer = {"Authorization": f"Bearer {token}"}
    assert client.get("/api/v1/fleet", headers=bearer).status_code == 200
    assert client.post("/api/v1/alerts/rules", headers=bearer,
                       json={"yaml": "name: x\nsend: hook"}).status_code == 403  # operator
    mine = [t for t in station.tokens.tokens("otto") if t.name == "grafana"]
    form = client.get("/login").text
    login_token = re.search(r'name="login_token" value="([^"]+)"', form).group(1)  # type: ignore[union-attr]
    client.post("/login", data={"username": "otto", "password": PASSWORD,
                                "login_token": login_token})
    csrf = re.search(r'data-csrf="([^"]+)"',  # type: ignore[union-attr]
                     client.get("/tokens").text).group(1)
    assert client.post("/tokens", data={"op": "revoke", "id": str(mine[0].id),
                                        "csrf_token": csrf},
                       follow_redirects=False).status_code == 303
    assert client.get("/api/v1/fleet", headers=bearer).status_code == 401
    actions = [(a.user, a.action) for a in station.auth.audit_log(limit=20)]
    assert ("otto", "token.create") in actions and ("otto", "token.revoke") in actions
