"""The station's web application over HTTP: log-in, roles, CSRF, escaping, every page renders.

A real station database filled through the store's own write API, real accounts, the real
FastAPI application driven in-process by its test client. The operator's DDS operations
are not reached in these tests (they are refused before); the browser tests run them
against a real black box.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from blackbox.health.ids import robot_resource_id
from blackbox.station.auth import Auth, Role
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from isolation import fresh_domain
from station_support import Unreachable, quick_auth

PASSWORD = "station password 1"
EVIL = "<script>alert(1)</script>"


@pytest.fixture
def station(tmp_path: Path) -> Iterator[tuple[StationStore, Auth, TestClient]]:
    path = tmp_path / "station.db"
    store = StationStore.open(path)
    auth = quick_auth(path)
    for name, role in (("vera", Role.VIEWER), ("otto", Role.OPERATOR), ("ada", Role.ADMIN)):
        auth.add_user(name, PASSWORD, role)
    rid = robot_resource_id("evil-bot")
    now = time.time()
    store.heard(rid, now)
    store.put_robot_id(rid, "evil-bot")
    store.put_entity(rid, 1, name="evil-bot", kind="robot", status="NOT_OPERATIONAL")
    store.put_entity(rid, 2, name=EVIL, kind="node", parent=1, status="NOT_OPERATIONAL",
                     cause=EVIL)
    store.put_entity(rid, 3, name="/usb_cam", kind="node", parent=1, status="OPERATIONAL")
    store.put_characteristic(rid, 10, entity=2, name=f"{EVIL} rate", unit="Hz")
    store.put_threshold(rid, 11, 10, "min", "min", 5.0)
    for i in range(5):
        store.put_value(rid, 10, now - 5 + i, 10.0 + i)
    store.put_diagnosis(rid, [EVIL], now)
    store.add_event(rid, now, "failure", dedup="f1", entity=EVIL, text=f"{EVIL} stopped")
    assert store.flush(force=True)
    app = create_app(auth, store, Unreachable())
    with TestClient(app, base_url="http://127.0.0.1") as client:
        yield store, auth, client
    auth.close()
    store.close()


def log_in(client: TestClient, name: str, password: str = PASSWORD) -> int:
    form = client.get("/login")
    token = re.search(r'name="login_token" value="([^"]+)"', form.text)
    assert token
    reply = client.post("/login", data={"username": name, "password": password,
                                        "login_token": token.group(1), "next": "/"},
                        follow_redirects=False)
    return reply.status_code


def csrf_of(client: TestClient) -> str:
    found = re.search(r'data-csrf="([^"]+)"', client.get("/").text)
    assert found
    return found.group(1)


def test_every_page_redirects_to_log_in_without_a_session(station) -> None:
    _, _, client = station
    for path in ("/", "/robot?r=evil-bot", "/entity?r=evil-bot&id=2", "/events", "/logs",
                 "/users", "/logs/1"):
        reply = client.get(path, follow_redirects=False)
        assert reply.status_code == 303, path
        assert reply.headers["location"].startswith("/login?next=")
    assert client.get("/api/stream", follow_redirects=False).status_code == 401
    assert client.post("/logs", data={"robot": "evil-bot"}).status_code == 401


def test_log_in_sets_a_strict_http_only_cookie_and_log_out_ends_the_session(station) -> None:
    _, auth, client = station
    form = client.get("/login")
    token = re.search(r'name="login_token" value="([^"]+)"', form.text).group(1)
    reply = client.post("/login", data={"username": "vera", "password": PASSWORD,
                                        "login_token": token}, follow_redirects=False)
    assert reply.status_code == 303
    cookie = next(h for h in reply.headers.get_list("set-cookie") if h.startswith("bb_session="))
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Secure" not in cookie
    assert client.get("/", follow_redirects=False).status_code == 200
    csrf = csrf_of(client)
    assert client.post("/logout", data={"csrf_token": csrf},
                       follow_redirects=False).status_code == 303
    assert client.get("/", follow_redirects=False).status_code == 303
    assert [a.action for a in auth.audit_log(limit=2)] == ["logout", "login"]


def test_log_in_without_the_form_token_is_refused(station) -> None:
    _, _, client = station
    reply = client.post("/login", data={"username": "vera", "password": PASSWORD},
                        follow_redirects=False)
    assert reply.status_code == 403


def test_wrong_passwords_are_refused_then_throttled(station) -> None:
    _, auth, client = station
    assert log_in(client, "otto", "not the password") == 401
    codes = [log_in(client, "otto", "not the password") for _ in range(4)]
    assert codes[-1] == 429
    assert log_in(client, "otto") == 429  # even the right password waits
    assert any(a.outcome == "throttled" for a in auth.audit_log())


def test_viewer_sees_everything_but_gets_403_on_logs_ibit_ack_and_users(station) -> None:
    _, auth, client = station
    assert log_in(client, "vera") == 303
    csrf = csrf_of(client)
    for path in ("/", "/robot?r=evil-bot", "/entity?r=evil-bot&id=2", "/events", "/logs"):
        assert client.get(path).status_code == 200, path
    assert client.post("/logs", data={"csrf_token": csrf, "robot": "evil-bot"}).status_code \
        == 403
    assert client.post("/ibit", data={"csrf_token": csrf, "robot": "evil-bot"}).status_code \
        == 403
    assert client.post("/ack", data={"csrf_token": csrf, "event": "1"}).status_code == 403
    assert client.get("/users").status_code == 403
    refused = {a.action for a in auth.audit_log() if a.outcome == "refused"}
    assert {"logs.request", "ibit.run", "alarm.ack"} <= refused


def test_posts_without_the_csrf_token_are_refused_and_audited(station) -> None:
    _, auth, client = station
    assert log_in(client, "ada") == 303
    for path, form in (("/logs", {"robot": "evil-bot"}), ("/ibit", {"robot": "evil-bot"}),
                       ("/ack", {"event": "1"}), ("/logout", {}),
                       ("/users", {"op": "add", "name": "mallory", "password": "x" * 12,
                                   "role": "admin"})):
        assert client.post(path, data=form).status_code == 403, path
        assert client.post(path, data={**form, "csrf_token": "forged"}).status_code == 403
    assert auth.user("mallory") is None
    assert client.get("/", follow_redirects=False).status_code == 200  # still logged in
    assert sum(a.detail == "missing or wrong CSRF token" for a in auth.audit_log()) == 10


def test_operator_acknowledges_an_alarm_and_admin_manages_users(station) -> None:
    store, auth, client = station
    assert log_in(client, "otto") == 303
    event = store.events("evil-bot", kinds=["failure"]).events[0]
    reply = client.post("/ack", data={"csrf_token": csrf_of(client), "event": str(event.id),
                                      "back": "/events"}, follow_redirects=False)
    assert reply.status_code == 303
    assert store.event(event.id).acknowledged_by == "otto"

    client.cookies.clear()
    assert log_in(client, "ada") == 303
    csrf = csrf_of(client)
    reply = client.post("/users", data={"csrf_token": csrf, "op": "add", "name": "nina",
                                        "password": "long enough pw", "role": "operator"},
                        follow_redirects=False)
    assert reply.status_code == 303
    assert auth.user("nina").role is Role.OPERATOR
    assert "nina" in client.get("/users").text
    reply = client.post("/users", data={"csrf_token": csrf, "op": "password", "name": "nina",
                                        "password": "another long pw"}, follow_redirects=False)
    assert reply.status_code == 303
    assert auth.log_in("nina", "another long pw", "test").session is not None
    actions = [a.action for a in auth.audit_log()]
    assert "alarm.ack" in actions and "user.add" in actions


def test_robot_supplied_names_are_rendered_as_text(station) -> None:
    _, _, client = station
    assert log_in(client, "vera") == 303
    for path in ("/robot?r=evil-bot", "/entity?r=evil-bot&id=2", "/events"):
        html = client.get(path).text
        assert EVIL not in html, path
        assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html, path
    assert "<script" not in client.get("/entity?r=evil-bot&id=2").text.replace(
        '<script src="', "")


def test_security_headers_forbid_inline_scripts_and_framing(station) -> None:
    _, _, client = station
    reply = client.get("/login")
    assert "script-src 'self'" in reply.headers["content-security-policy"]
    assert reply.headers["x-frame-options"] == "DENY"


def test_unknown_robot_and_bad_filters_are_clear_errors(station) -> None:
    _, _, client = station
    assert log_in(client, "vera") == 303
    reply = client.get("/robot?r=nobody")
    assert reply.status_code == 404 and "nobody" in reply.text
    assert client.get("/events?since=yesterday").status_code == 400
    assert client.get("/events?kind=bogus").status_code == 400
    assert client.get("/").status_code == 200  # the station keeps serving


def test_a_robot_that_stops_talking_turns_grey_unknown(tmp_path: Path) -> None:
    now = [time.time()]
    path = tmp_path / "station.db"
    store = StationStore.open(path, stale_after=10.0, clock=lambda: now[0])
    auth = quick_auth(path)
    auth.add_user("vera", PASSWORD, Role.VIEWER)
    rid = robot_resource_id("quiet-bot")
    store.heard(rid, now[0])
    store.put_robot_id(rid, "quiet-bot")
    store.put_entity(rid, 1, name="quiet-bot", kind="robot", status="OPERATIONAL")
    store.put_entity(rid, 2, name="/node", kind="node", parent=1, status="OPERATIONAL")
    assert store.flush(force=True)
    try:
        with TestClient(create_app(auth, store, Unreachable()),
                        base_url="http://127.0.0.1") as client:
            assert log_in(client, "vera") == 303
            row = client.get("/").text
            assert 'h-operational" data-field="status">OPERATIONAL' in row
            now[0] += 11.0
            fleet = client.get("/").text
            assert 'h-unknown" data-field="status">UNKNOWN' in fleet
            assert 'data-field="silent">silent<' in fleet
            robot = client.get("/robot?r=quiet-bot").text
            assert 'data-name="/node"' in robot
            assert re.search(r'kind-node h-unknown" data-entity="2"', robot)
    finally:
        auth.close()
        store.close()


@pytest.mark.skipif(not Path("/usr/bin/openssl").exists(), reason="needs openssl")
def test_over_tls_cookies_are_secure(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys

    import httpx

    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["/usr/bin/openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes",
                    "-keyout", str(key), "-out", str(cert), "-days", "1", "-subj",
                    "/CN=127.0.0.1"], check=True, capture_output=True, timeout=60)
    db, ready = tmp_path / "station.db", tmp_path / "url"
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    add = subprocess.run([sys.executable, "-m", "blackbox", "station", "user", "add", "ana",
                          "--role", "viewer", "--db", str(db)], input=PASSWORD + "\n",
                         capture_output=True, text=True, timeout=60, env=env)
    assert add.returncode == 0, add.stderr
    station = subprocess.Popen([sys.executable, "-m", "blackbox", "station", "--db", str(db),
                                "--bind", "127.0.0.1:0", "--domain", str(fresh_domain()),
                                "--tls-cert", str(cert), "--tls-key", str(key),
                                "--ready-file", str(ready), "--duration", "60"], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and time.monotonic() < deadline and station.poll() is None:
            time.sleep(0.1)
        url = ready.read_text().strip()
        assert url.startswith("https://127.0.0.1:")
        with httpx.Client(base_url=url, verify=False) as client:
            form = client.get("/login")
            assert "Secure" in form.headers["set-cookie"]
            assert form.headers["strict-transport-security"] == "max-age=31536000"
            token = re.search(r'name="login_token" value="([^"]+)"', form.text).group(1)
            reply = client.post("/login", data={"username": "ana", "password": PASSWORD,
                                                "login_token": token})
            cookie = next(h for h in reply.headers.get_list("set-cookie")
                          if h.startswith("bb_session="))
            assert "Secure" in cookie and "HttpOnly" in cookie
    finally:
        station.send_signal(signal.SIGINT)
        try:
            station.wait(timeout=15)
        except subprocess.TimeoutExpired:
            station.kill()
    assert station.returncode == 0, station.stderr.read().decode() if station.stderr else ""


def test_user_add_reads_the_password_from_stdin_and_refuses_bad_input(tmp_path: Path) -> None:
    import subprocess
    import sys

    db = tmp_path / "station.db"

    def add(name: str, password: str, role: str = "operator") -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "blackbox", "station", "user", "add", name,
                               "--role", role, "--db", str(db)], input=password + "\n",
                              capture_output=True, text=True, timeout=60)

    assert add("otto", PASSWORD).returncode == 0
    for result, message in ((add("otto", PASSWORD), "exists already"),
                            (add("eve", "short"), "at least 10 characters"),
                            (add("<b>", PASSWORD), "a user name is")):
        assert result.returncode == 2
        assert message in result.stderr and "Traceback" not in result.stderr
    listed = subprocess.run([sys.executable, "-m", "blackbox", "station", "user", "list",
                             "--db", str(db)], capture_output=True, text=True, timeout=60)
    assert listed.stdout.split() == ["otto", "operator"]
    passwd = subprocess.run([sys.executable, "-m", "blackbox", "station", "user", "passwd",
                             "otto", "--db", str(db)], input="a new password\n",
                            capture_output=True, text=True, timeout=60)
    assert passwd.returncode == 0, passwd.stderr
    store = StationStore.open(db)
    auth = Auth(db)
    try:
        assert auth.log_in("otto", "a new password", "test").session is not None
    finally:
        auth.close()
        store.close()
