"""The station's web application against an attacker who has read its code.

A real uvicorn on 127.0.0.1 serving the real application (as ``blackbox station`` does,
with the same :func:`~blackbox.station.web.limits.uvicorn_options`), real accounts in a
real SQLite file, plain HTTP requests with httpx. Each test is one finding of issue 24:
a live stream outliving its session, log-in throttling that locks the real user out,
forged ``X-Forwarded-For``, unauthenticated uploads spooled to disk, ids that crash a
route, weak passwords, an admin-less station.
"""

from __future__ import annotations

import re
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest
import uvicorn

from blackbox.health.ids import robot_resource_id
from blackbox.station.auth import Auth, Role, StationAuthError
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from blackbox.station.web.limits import uvicorn_options
from station_support import Unreachable, quick_auth

PASSWORD = "station password 1"
HUGE = 10**20


@contextmanager
def serve(tmp_path: Path, trusted_proxies: tuple[str, ...] = ()) -> Iterator[
        tuple[str, Auth]]:
    """The station on 127.0.0.1 with vera (viewer), otto (operator) and ada (admin)."""
    path = tmp_path / "station.db"
    store = StationStore.open(path)
    auth = quick_auth(path)
    for name, role in (("vera", Role.VIEWER), ("otto", Role.OPERATOR), ("ada", Role.ADMIN)):
        auth.add_user(name, PASSWORD, role)
    rid = robot_resource_id("ward-bot")
    store.heard(rid, time.time())
    store.put_robot_id(rid, "ward-bot")
    store.put_entity(rid, 1, name="ward-bot", kind="robot", status="OPERATIONAL")
    store.add_event(rid, time.time(), "failure", dedup="f1", entity="/cam", text="stopped")
    assert store.flush(force=True)
    stop = threading.Event()
    server = uvicorn.Server(uvicorn.Config(create_app(auth, store, Unreachable(), stop=stop),
                                           log_level="warning",
                                           **uvicorn_options(trusted_proxies)))
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started and thread.is_alive() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started, "uvicorn did not start within 20 s"
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}", auth
    finally:
        stop.set()  # ends the live streams first, else uvicorn waits for them
        server.should_exit = True
        thread.join(timeout=15)
        auth.close()
        store.close()


def log_in(client: httpx.Client, name: str, password: str = PASSWORD,
           headers: dict[str, str] | None = None) -> httpx.Response:
    form = client.get("/login")
    token = re.search(r'name="login_token" value="([^"]+)"', form.text)
    assert token, form.text[:300]
    return client.post("/login", data={"username": name, "password": password,
                                       "login_token": token.group(1), "next": "/"},
                       headers=headers or {})


def csrf_of(client: httpx.Client) -> str:
    found = re.search(r'data-csrf="([^"]+)"', client.get("/").text)
    assert found
    return found.group(1)


def test_a_live_stream_ends_on_log_out_removal_password_change_and_role_change(
        tmp_path: Path) -> None:
    with serve(tmp_path) as (url, auth):
        def log_out(client: httpx.Client) -> None:
            assert client.post("/logout", data={"csrf_token": csrf_of(client)}).status_code \
                == 303

        actions: dict[str, Callable[[httpx.Client], None]] = {
            "log-out": log_out,
            "password change": lambda _: auth.set_password("vera", "a new pass phrase",
                                                           by="ada", address="test"),
            "role change": lambda _: auth.set_role("vera", Role.OPERATOR, by="ada",
                                                   address="test"),
            "removal": lambda _: auth.remove_user("vera", by="ada", address="test"),
        }
        for what, act in actions.items():
            if auth.user("vera") is None:
                auth.add_user("vera", PASSWORD, Role.VIEWER)
            auth.set_password("vera", PASSWORD, by="test", address="test")
            auth.set_role("vera", Role.VIEWER, by="test", address="test")
            # a read timeout of 5 s: the stream wakes at least every 0.5 s to re-check
            with httpx.Client(base_url=url, follow_redirects=False, timeout=5.0) as client:
                assert log_in(client, "vera").status_code == 303
                with client.stream("GET", "/api/stream?view=fleet") as stream:
                    lines = stream.iter_lines()
                    assert "event: state" in next(line for line in lines
                                                  if line.startswith("event:"))
                    act(client)
                    started = time.monotonic()
                    try:
                        ended = any(line == "event: end" for line in lines)
                    except httpx.ReadTimeout:
                        ended = False
                    assert ended, f"the stream went on after the {what}"
                    assert time.monotonic() - started < 3.0, what


def test_the_right_password_from_another_address_works_while_a_guesser_is_throttled(
        tmp_path: Path) -> None:
    with serve(tmp_path, trusted_proxies=("127.0.0.1",)) as (url, _), \
            httpx.Client(base_url=url, follow_redirects=False, timeout=30) as client:
        guesser = {"X-Forwarded-For": "198.51.100.7"}
        codes = [log_in(client, "otto", "not the password", guesser).status_code
                 for _ in range(5)]
        assert codes[:3] == [401, 401, 401] and codes[-1] == 429, codes
        assert log_in(client, "otto", PASSWORD, guesser).status_code == 429
        assert log_in(client, "otto", PASSWORD,
                      {"X-Forwarded-For": "192.0.2.10"}).status_code == 303
        client.cookies.clear()  # a console of its own
        for i in range(25):  # many names failing at one console lock nobody else out there
            log_in(client, f"typo{i}", "not the password", {"X-Forwarded-For": "192.0.2.20"})
        assert log_in(client, "vera", PASSWORD,
                      {"X-Forwarded-For": "192.0.2.20"}).status_code == 303


def test_forwarded_headers_are_ignored_unless_a_trusted_proxy_sends_them(
        tmp_path: Path) -> None:
    with serve(tmp_path) as (url, auth), \
            httpx.Client(base_url=url, follow_redirects=False, timeout=30) as client:
        codes = [log_in(client, "otto", "not the password",
                        {"X-Forwarded-For": f"203.0.113.{i}"}).status_code for i in range(5)]
        assert codes[-1] == 429, codes  # a new forged address per try does not help
        addresses = {e.address for e in auth.audit_log(action="login")}
        assert addresses == {"127.0.0.1"}, addresses
    (tmp_path / "proxied").mkdir()
    with serve(tmp_path / "proxied", trusted_proxies=("127.0.0.1",)) as (url, auth), \
            httpx.Client(base_url=url, follow_redirects=False, timeout=30) as client:
        log_in(client, "otto", "not the password", {"X-Forwarded-For": "203.0.113.9"})
        assert {e.address for e in auth.audit_log(action="login")} == {"203.0.113.9"}


def test_bodies_are_capped_before_reading_and_multipart_is_refused(tmp_path: Path) -> None:
    with serve(tmp_path) as (url, _), \
            httpx.Client(base_url=url, follow_redirects=False, timeout=30) as client:
        token = re.search(r'name="login_token" value="([^"]+)"',
                          client.get("/login").text)
        assert token

        def chunks() -> Iterator[bytes]:  # no Content-Length: counted while read
            for _ in range(16):
                yield b"a" * 4096
            yield b"a"  # one byte over the 64 KiB limit

        assert client.post("/login", content=chunks(),
                           headers={"content-type": "application/x-www-form-urlencoded"}
                           ).status_code == 413
        for content_type, status in (("multipart/form-data; boundary=x", 415),
                                     ("application/x-www-form-urlencoded", 413)):
            assert answer_to_headers_only(url, content_type, 200_000_000).startswith(
                f"HTTP/1.1 {status} "), content_type
        small = client.post("/login", data={"login_token": token.group(1)},
                            files={"file": ("small.bin", b"\0" * 100)})
        assert small.status_code == 415
        assert "multipart" in small.text


def answer_to_headers_only(url: str, content_type: str, length: int) -> str:
    """The status line the station answers to a POST /login that announces ``length``
    bytes and sends none of them: an answer proves nothing was read or spooled."""
    port = int(url.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=10) as conn:
        conn.sendall(f"POST /login HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                     f"{content_type}\r\nContent-Length: {length}\r\n\r\n".encode())
        reply = conn.recv(4096).decode(errors="replace")
    return reply.splitlines()[0] if reply else ""


def test_ids_out_of_range_are_answered_400_not_500(tmp_path: Path) -> None:
    with serve(tmp_path) as (url, _), \
            httpx.Client(base_url=url, follow_redirects=False, timeout=30) as client:
        assert log_in(client, "otto").status_code == 303
        for path in (f"/entity?r=ward-bot&id={HUGE}", f"/logs/{HUGE}",
                     f"/logs/{HUGE}/download", f"/ibit/{HUGE}", f"/ibit/-{HUGE}",
                     f"/api/stream?view=ibit&id={HUGE}", "/entity?r=ward-bot&id=-1",
                     f"/robot?r=%23{HUGE}", f"/api/stream?view=robot&r=%23{HUGE}"):
            reply = client.get(path)
            assert reply.status_code in (400, 404), (path, reply.status_code)
            assert "Traceback" not in reply.text
        acked = client.post("/ack", data={"csrf_token": csrf_of(client), "event": str(HUGE),
                                          "back": "/"})
        assert acked.status_code == 404


def test_weak_passwords_and_the_last_admin_are_refused_on_the_users_page(
        tmp_path: Path) -> None:
    with serve(tmp_path) as (url, auth), \
            httpx.Client(base_url=url, follow_redirects=False, timeout=30) as client:
        assert log_in(client, "ada").status_code == 303
        csrf = csrf_of(client)
        for password, words in ((" " * 10, "only spaces"), ("nina.nurse", "user name"),
                                ("x" * 2000, "at most 256"), ("qwertyuiop", "breaches"),
                                ("abababababab", "repeated")):
            reply = client.post("/users", data={"csrf_token": csrf, "op": "add",
                                                "name": "nina.nurse", "password": password,
                                                "role": "operator"})
            assert reply.status_code == 400 and words in reply.text, (password[:12], words)
        assert auth.user("nina.nurse") is None
        reply = client.post("/users", data={"csrf_token": csrf, "op": "role", "name": "ada",
                                            "role": "operator"})
        assert reply.status_code == 400 and "last admin" in reply.text
        with pytest.raises(StationAuthError, match="last admin"):
            auth.remove_user("ada", by="cli", address="local")
        auth.add_user("root2", "second admin pass", Role.ADMIN)
        assert client.post("/users", data={"csrf_token": csrf, "op": "role", "name": "ada",
                                           "role": "operator"}).status_code == 303


def test_no_hsts_over_plain_http(tmp_path: Path) -> None:
    """HSTS is sent under TLS only (tests/test_station_web_http.py checks that side)."""
    with serve(tmp_path) as (url, _), httpx.Client(base_url=url, timeout=30) as client:
        assert "strict-transport-security" not in client.get("/login").headers
