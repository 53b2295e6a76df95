"""Channels that deliver a notification: a signed webhook and e-mail over SMTP.

Each channel does one attempt and says how it went (:class:`Outcome`); retrying is the
outbox's job. An attempt is bounded in time (the channel's timeout) and in what it reads
back, and never follows a redirect: a webhook that answers 3xx is misconfigured, and
following it would send a signed alert to a host nobody configured.

Webhook body (``schema`` ``blackbox.alert/1``) and headers are documented in
docs/station.md "Alerts". The signature is ``X-Blackbox-Signature: sha256=<hex>`` of
HMAC-SHA256 over ``<X-Blackbox-Timestamp>.<body>`` with the channel's secret, so a receiver
can refuse replays of old bodies.
"""

from __future__ import annotations

import hashlib
import hmac
import http.client
import json
import smtplib
import ssl
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from email.message import EmailMessage
from typing import Any, Protocol

from blackbox.station.alerts.rules import ChannelSpec, EmailSettings, WebhookSettings

SIGNATURE_HEADER = "X-Blackbox-Signature"
TIMESTAMP_HEADER = "X-Blackbox-Timestamp"
DELIVERY_HEADER = "X-Blackbox-Delivery"
MAX_REPLY = 65536


@dataclass(frozen=True, slots=True)
class Outcome:
    ok: bool
    detail: str


@dataclass(frozen=True, slots=True)
class Notification:
    """What goes out: ``delivery`` is the outbox row (receivers may dedup on it)."""

    delivery: int
    payload: dict[str, Any]

    @property
    def subject(self) -> str:
        p = self.payload
        alert = p.get("alert", {})
        prefix = {"alert": "ALERT", "resolved": "RESOLVED", "escalation": "ESCALATED",
                  "digest": "DIGEST", "test": "TEST"}.get(str(p.get("type")), "ALERT")
        return (f"[{prefix}] {alert.get('robot', '')} {alert.get('entity', '')}: "
                f"{alert.get('kind', '')} ({p.get('rule', '')})")[:200]

    def body_text(self) -> str:
        p = self.payload
        alert = p.get("alert", {})
        lines = [str(p.get("summary", "")), ""]
        lines += [f"{k}: {alert[k]}" for k in ("robot", "entity", "kind", "status", "text",
                                                "count", "state") if k in alert]
        if p.get("suppressed"):
            lines.append(f"suppressed by the rate limit: {p['suppressed']}")
            lines += [f"  {s}" for s in p.get("suppressed_examples", [])]
        if p.get("ack_url"):
            lines += ["", f"Acknowledge (log-in required): {p['ack_url']}"]
        return "\n".join(lines) + "\n"


class Channel(Protocol):
    name: str

    def send(self, notification: Notification) -> Outcome: ...


def sign(secret: str, timestamp: str, body: bytes) -> str:
    """The value of :data:`SIGNATURE_HEADER` for ``body`` sent at ``timestamp``."""
    mac = hmac.new(secret.encode(), timestamp.encode() + b"." + body, hashlib.sha256)
    return "sha256=" + mac.hexdigest()


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, req: urllib.request.Request, fp: Any, code: int, msg: str,
                         headers: Any, newurl: str) -> None:
        return None  # the 3xx is then raised as an HTTPError and reported


class WebhookChannel:
    def __init__(self, name: str, settings: WebhookSettings) -> None:
        self.name = name
        self.settings = settings
        self._opener = urllib.request.build_opener(_NoRedirect())

    def send(self, notification: Notification) -> Outcome:
        body = json.dumps(notification.payload, sort_keys=True).encode()
        stamp = f"{time.time():.3f}"
        request = urllib.request.Request(self.settings.url, data=body, method="POST", headers={
            "Content-Type": "application/json", "User-Agent": "blackbox-station",
            TIMESTAMP_HEADER: stamp, DELIVERY_HEADER: str(notification.delivery),
            SIGNATURE_HEADER: sign(self.settings.secret, stamp, body)})
        try:
            with self._opener.open(request, timeout=self.settings.timeout) as reply:
                reply.read(MAX_REPLY)
                return Outcome(True, f"HTTP {reply.status}")
        except urllib.error.HTTPError as exc:
            if 300 <= exc.code < 400:
                where = exc.headers.get("Location", "?")
                return Outcome(False, f"HTTP {exc.code} redirect to {where[:200]} not followed")
            return Outcome(False, f"HTTP {exc.code} {str(exc.reason)[:200]}")
        except TimeoutError:
            return Outcome(False, f"no answer within {self.settings.timeout:g} s")
        except urllib.error.URLError as exc:
            reason = exc.reason
            if isinstance(reason, TimeoutError):
                return Outcome(False, f"no answer within {self.settings.timeout:g} s")
            return Outcome(False, f"cannot connect: {str(reason)[:200]}")
        except (OSError, http.client.HTTPException, ValueError) as exc:
            return Outcome(False, f"{type(exc).__name__}: {str(exc)[:200]}")


class EmailChannel:
    def __init__(self, name: str, settings: EmailSettings,
                 tls_context: ssl.SSLContext | None = None) -> None:
        self.name = name
        self.settings = settings
        self.tls_context = tls_context or ssl.create_default_context()

    def send(self, notification: Notification) -> Outcome:
        s = self.settings
        message = EmailMessage()
        message["From"] = s.sender
        message["To"] = ", ".join(s.to)
        message["Subject"] = notification.subject
        message["X-Blackbox-Delivery"] = str(notification.delivery)
        message.set_content(notification.body_text())
        try:
            with smtplib.SMTP(s.host, s.port, timeout=s.timeout) as smtp:
                smtp.ehlo()
                if s.starttls:
                    smtp.starttls(context=self.tls_context)
                    smtp.ehlo()
                if s.username:
                    smtp.login(s.username, s.password)
                refused = smtp.send_message(message)
        except smtplib.SMTPNotSupportedError:
            return Outcome(False, f"{s.host}:{s.port} does not offer STARTTLS")
        except smtplib.SMTPAuthenticationError as exc:
            return Outcome(False, f"log-in refused: {exc.smtp_code} {_text(exc.smtp_error)}")
        except smtplib.SMTPRecipientsRefused as exc:
            return Outcome(False, f"recipients refused: {', '.join(exc.recipients)[:200]}")
        except smtplib.SMTPResponseException as exc:
            return Outcome(False, f"SMTP {exc.smtp_code} {_text(exc.smtp_error)}")
        except (smtplib.SMTPException, OSError) as exc:
            return Outcome(False, f"{type(exc).__name__}: {str(exc)[:200]}")
        if refused:
            return Outcome(False, f"recipients refused: {', '.join(refused)[:200]}")
        return Outcome(True, f"accepted by {s.host}:{s.port} for {len(s.to)} recipient(s)")


def _text(raw: bytes | str) -> str:
    text = raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)
    return text[:200]


def make_channel(spec: ChannelSpec, tls_context: ssl.SSLContext | None = None) -> Channel:
    if spec.webhook is not None:
        return WebhookChannel(spec.name, spec.webhook)
    assert spec.email is not None
    return EmailChannel(spec.name, spec.email, tls_context)
