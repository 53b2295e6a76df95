"""E-mail notifications through a real SMTP server (aiosmtpd on 127.0.0.1) that requires
STARTTLS before log-in: accepted with the right account, refused (and retried, then a
visible problem) with a wrong one."""

from __future__ import annotations

import email
import socket
import ssl
import time
from pathlib import Path

import pytest

from alert_support import robot_with_entity, rules_file, smtp_server
from blackbox.station.alerts.channels import EmailChannel, Notification
from blackbox.station.alerts.rules import load_alert_config
from blackbox.station.alerts.service import AlertService
from blackbox.station.store import StationStore
from conftest import wait_for

pytest.importorskip("aiosmtpd")


def mail_config(tmp: Path, port: int, password: str) -> Path:
    return rules_file(tmp, f"""\
station_url: http://127.0.0.1:8080
delivery: {{attempts: 2, backoff: 0.05}}
channels:
  mail:
    type: email
    host: 127.0.0.1
    port: {port}
    starttls: true
    username: alerts
    password: "{password}"
    from: station@example.org
    to: [oncall@example.org, lead@example.org]
    timeout: 5
rules:
  - name: all failures
    match: {{kind: failure}}
    send: mail
""")


def trusting(cert: Path) -> ssl.SSLContext:
    return ssl.create_default_context(cafile=str(cert))


def test_an_alert_is_mailed_over_starttls_after_log_in(tmp_path: Path) -> None:
    store = StationStore.open(tmp_path / "station.db")
    rid = robot_with_entity(store)
    with smtp_server(tmp_path, "alerts", "mail password 1") as (box, cert):
        config = load_alert_config(mail_config(tmp_path, box.port, "mail password 1"))
        channel = EmailChannel("mail", config.channels["mail"].email, trusting(cert))  # type: ignore[arg-type]
        service = AlertService(store, tmp_path / "station.db", config, tick=0.1,
                               channels={"mail": channel})
        service.start()
        try:
            store.add_event(rid, time.time(), "failure", dedup="f1", entity="/usb_cam",
                            text="/usb_cam stopped publishing")
            assert store.flush(force=True)
            envelope = box.wait_for(1, timeout=15)[0]
        finally:
            service.stop()
            store.close()
    assert box.logins == ["alerts"]
    assert envelope.rcpt_tos == ["oncall@example.org", "lead@example.org"]
    message = email.message_from_bytes(envelope.content)
    assert message["Subject"].startswith("[ALERT] tug-1 /usb_cam: failure")
    body = message.get_payload(decode=True).decode()
    assert "/usb_cam stopped publishing" in body
    assert "Acknowledge (log-in required): http://127.0.0.1:8080/alerts/1" in body


def test_a_server_that_refuses_the_log_in_is_retried_then_shown(tmp_path: Path) -> None:
    store = StationStore.open(tmp_path / "station.db")
    rid = robot_with_entity(store)
    with smtp_server(tmp_path, "alerts", "mail password 1") as (box, cert):
        config = load_alert_config(mail_config(tmp_path, box.port, "wrong password"))
        channel = EmailChannel("mail", config.channels["mail"].email, trusting(cert))  # type: ignore[arg-type]
        service = AlertService(store, tmp_path / "station.db", config, tick=0.1,
                               channels={"mail": channel})
        service.start()
        try:
            store.add_event(rid, time.time(), "failure", dedup="f1", entity="/usb_cam")
            assert store.flush(force=True)
            assert wait_for(lambda: any(e.state == "failed"
                                        for e in service.outbox.entries()), 15), \
                "waited for the mail to fail for good"
            entry = service.outbox.entries()[0]
        finally:
            service.stop()
            store.close()
    assert entry.attempts == 2 and "log-in refused: 535" in entry.last_error
    assert box.messages == []


def test_a_server_without_starttls_is_refused_before_the_password_is_sent(
        tmp_path: Path) -> None:
    from aiosmtpd.controller import Controller

    class Sink:
        async def handle_DATA(self, server: object, session: object, envelope: object) -> str:
            return "250 OK"

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    controller = Controller(Sink(), hostname="127.0.0.1", port=port)
    controller.start()
    try:
        config = load_alert_config(mail_config(tmp_path, port, "mail password 1"))
        assert config.channels["mail"].email is not None
        outcome = EmailChannel("mail", config.channels["mail"].email).send(
            Notification(1, {"type": "test", "summary": "x"}))
    finally:
        controller.stop()
    assert not outcome.ok and "does not offer STARTTLS" in outcome.detail
