"""Helpers of the alerting tests: a real webhook receiver on 127.0.0.1 that can fail, hang
or redirect on purpose, and a real SMTP server (aiosmtpd) with STARTTLS and log-in."""

from __future__ import annotations

import hashlib
import hmac
import http.server
import json
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from blackbox.health.ids import robot_resource_id
from blackbox.station.store import StationStore

SECRET = "webhook secret of the tests"


@dataclass
class Received:
    headers: dict[str, str]
    body: bytes
    at: float

    @property
    def json(self) -> dict[str, Any]:
        return dict(json.loads(self.body))

    def signed_by(self, secret: str) -> bool:
        stamp = self.headers["X-Blackbox-Timestamp"]
        mac = hmac.new(secret.encode(), stamp.encode() + b"." + self.body, hashlib.sha256)
        return hmac.compare_digest("sha256=" + mac.hexdigest(),
                                   self.headers["X-Blackbox-Signature"])


@dataclass
class Receiver:
    """``fail_first`` requests answer 500; ``mode`` ``hang`` never answers (until closed),
    ``redirect`` answers 307 to another host. ``received`` holds accepted requests, and
    ``attempts`` counts every request."""

    url: str = ""
    fail_first: int = 0
    mode: str = "ok"
    attempts: int = 0
    received: list[Received] = field(default_factory=list)
    cond: threading.Condition = field(default_factory=threading.Condition)
    release: threading.Event = field(default_factory=threading.Event)

    def wait_for(self, count: int, timeout: float) -> list[Received]:
        with self.cond:
            ok = self.cond.wait_for(lambda: len(self.received) >= count, timeout)
        assert ok, f"the receiver got {len(self.received)} of {count} webhooks in {timeout} s"
        return list(self.received)

    def wait_for_one(self, match: Callable[[Received], bool], what: str,
                     timeout: float) -> Received:
        """The first accepted request that ``match`` accepts (others may come first)."""
        with self.cond:
            ok = self.cond.wait_for(lambda: any(match(r) for r in self.received), timeout)
            assert ok, f"the receiver got no {what} in {timeout} s " \
                       f"({len(self.received)} other webhooks)"
            return next(r for r in self.received if match(r))

    def wait_attempts(self, count: int, timeout: float) -> None:
        with self.cond:
            ok = self.cond.wait_for(lambda: self.attempts >= count, timeout)
        assert ok, f"the receiver saw {self.attempts} of {count} attempts in {timeout} s"


@contextmanager
def webhook_receiver(fail_first: int = 0, mode: str = "ok",
                     port: int = 0) -> Iterator[Receiver]:
    state = Receiver(fail_first=fail_first, mode=mode)

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            length = int(self.headers.get("Content-Length", "0"))
            body = self.rfile.read(length)
            with state.cond:
                state.attempts += 1
                attempt = state.attempts
                state.cond.notify_all()
            if state.mode == "hang":
                state.release.wait(30)
                return
            if state.mode == "redirect":
                self.send_response(307)
                self.send_header("Location", "http://127.0.0.1:9/elsewhere")
                self.end_headers()
                return
            if attempt <= state.fail_first:
                self.send_response(500)
                self.end_headers()
                self.wfile.write(b"down for maintenance")
                return
            self.send_response(204)
            self.end_headers()
            with state.cond:
                state.received.append(Received(dict(self.headers.items()), body,
                                               time.time()))
                state.cond.notify_all()

        def log_message(self, format: str, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
    server.daemon_threads = True
    state.url = f"http://127.0.0.1:{server.server_address[1]}/hook"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield state
    finally:
        state.release.set()
        server.shutdown()
        server.server_close()


def rules_file(tmp: Path, text: str) -> Path:
    path = tmp / "alerts.yaml"
    path.write_text(text)
    return path


def robot_with_entity(store: StationStore, robot: str = "tug-1",
                      entity: str = "/usb_cam") -> int:
    rid = robot_resource_id(robot)
    now = time.time()
    store.heard(rid, now)
    store.put_robot_id(rid, robot)
    store.put_entity(rid, 1, name=robot, kind="robot", status="OPERATIONAL")
    store.put_entity(rid, 2, name=entity, kind="node", parent=1, status="OPERATIONAL")
    assert store.flush(force=True)
    return rid


def self_signed_cert(tmp: Path) -> tuple[Path, Path]:
    """A throw-away certificate for the SMTP server's STARTTLS (openssl from Debian)."""
    cert, key = tmp / "smtp.crt", tmp / "smtp.key"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
                    "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
                    "-keyout", str(key), "-out", str(cert)], check=True, capture_output=True,
                   timeout=60)
    return cert, key


@dataclass
class Mailbox:
    """What the SMTP server accepted, and how the client got there."""

    host: str
    port: int
    messages: list[Any] = field(default_factory=list)
    logins: list[str] = field(default_factory=list)
    cond: threading.Condition = field(default_factory=threading.Condition)

    def wait_for(self, count: int, timeout: float) -> list[Any]:
        with self.cond:
            ok = self.cond.wait_for(lambda: len(self.messages) >= count, timeout)
        assert ok, f"the SMTP server got {len(self.messages)} of {count} messages in {timeout} s"
        return list(self.messages)


@contextmanager
def smtp_server(tmp: Path, user: str, password: str) -> Iterator[tuple[Mailbox, Path]]:
    """aiosmtpd on 127.0.0.1 requiring STARTTLS before AUTH (LOGIN/PLAIN) and mail; yields
    the mailbox and the certificate a client must trust."""
    import ssl

    from aiosmtpd.controller import Controller
    from aiosmtpd.smtp import AuthResult, LoginPassword

    cert, key = self_signed_cert(tmp)
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.load_cert_chain(str(cert), str(key))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    box = Mailbox("127.0.0.1", port)

    def authenticate(server: Any, session: Any, envelope: Any, mechanism: str,
                     auth_data: Any) -> AuthResult:
        ok = isinstance(auth_data, LoginPassword) and auth_data.login == user.encode() \
            and auth_data.password == password.encode()
        if ok:
            box.logins.append(user)
        return AuthResult(success=ok, handled=False)  # aiosmtpd answers 235 or 535

    class Handler:
        async def handle_DATA(self, server: Any, session: Any, envelope: Any) -> str:
            with box.cond:
                box.messages.append(envelope)
                box.cond.notify_all()
            return "250 OK"

    controller = Controller(Handler(), hostname="127.0.0.1", port=port, tls_context=context,
                            require_starttls=True, authenticator=authenticate,
                            auth_require_tls=True, auth_exclude_mechanism=["LOGIN"])
    controller.start()
    try:
        yield box, cert
    finally:
        controller.stop()
