"""The alerting pages: alerts with acknowledgement, rules with "send a test notification",
the count of events no rule matched, and each user's API tokens.

The page helpers (session, CSRF, role checks, rendering) are the application's own,
passed in as :class:`PageTools`, so these pages are held to exactly the same rules.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import RedirectResponse, Response

from blackbox.station.alerts.engine import AlertRuleError
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Role, Session, StationAuthError
from blackbox.station.tokens import ApiTokens


@dataclass(frozen=True, slots=True)
class PageTools:
    page: Callable[..., Response]
    require: Callable[..., Session]
    change: Callable[[Request, str, Role], Awaitable[tuple[Session, dict[str, str], str]]]
    address: Callable[[Request], str]


def mount_alert_pages(app: FastAPI, tools: PageTools, alerts: AlertService | None,
                      tokens: ApiTokens) -> None:
    def service() -> AlertService:
        if alerts is None:
            raise HTTPException(404, "alerting is not enabled on this station "
                                "(blackbox station --alerts FILE)")
        return alerts

    def alerts_page(request: Request, session: Session, status: int = 200,
                    message: str = "", draft: str = "") -> Response:
        s = service()
        now = s.clock()
        unmatched = s.engine.unmatched(now - 3600)
        return tools.page(request, "alerts.html", session, status=status, nav="alerts",
                          alerts=s.engine.alerts(limit=100), rules=s.engine.rules,
                          unmatched=unmatched, failed=s.outbox.entries(state="failed",
                                                                       limit=20),
                          message=message, draft=draft)

    @app.get("/alerts")
    async def alert_list(request: Request) -> Response:
        return alerts_page(request, tools.require(request))

    @app.get("/alerts/{alert_id}")
    async def alert_detail(request: Request, alert_id: int) -> Response:
        session = tools.require(request)
        s = service()
        alert = s.engine.alert(alert_id)
        if alert is None:
            raise HTTPException(404, "no such alert")
        return tools.page(request, "alert.html", session, nav="alerts", alert=alert,
                          deliveries=s.outbox.entries(alert_id=alert_id, limit=50))

    @app.post("/alerts/{alert_id}/ack")
    async def alert_ack(request: Request, alert_id: int) -> Response:
        session, form, _ = await tools.change(request, "alert.ack", Role.OPERATOR)
        s = service()
        try:
            await asyncio.to_thread(s.engine.acknowledge, alert_id, session.user.name,
                                    s.clock(), "page")
        except LookupError:
            raise HTTPException(404, "no such alert") from None
        s.wake()
        back = form.get("back", "")
        return RedirectResponse(back if back.startswith("/alerts") else "/alerts",
                                status_code=303)

    @app.post("/alerts/rules")
    async def rule_change(request: Request) -> Response:
        session, form, _ = await tools.change(request, "alert.rule", Role.ADMIN)
        s = service()
        op = form.get("op", "")
        try:
            if op == "add":
                s.engine.add_rule(form.get("yaml", ""), session.user.name, s.clock())
            elif op == "remove":
                s.engine.remove_rule(form.get("name", ""), session.user.name)
            elif op == "test":
                s.engine.send_test(form.get("name", ""), session.user.name, s.clock())
                s.wake()
                return alerts_page(request, session, message="Test notification queued for "
                                   f"rule {form.get('name', '')!r}; see the deliveries below.")
            else:
                raise AlertRuleError(f"unknown operation {op[:20]!r}")
        except AlertRuleError as exc:
            return alerts_page(request, session, status=400, message=str(exc),
                               draft=form.get("yaml", ""))
        return RedirectResponse("/alerts", status_code=303)

    @app.get("/tokens")
    async def token_list(request: Request) -> Response:
        session = tools.require(request)
        return tokens_page(request, session)

    def tokens_page(request: Request, session: Session, created: str = "",
                    message: str = "", status: int = 200) -> Response:
        mine = tokens.tokens(None if session.user.role >= Role.ADMIN else session.user.name)
        return tools.page(request, "tokens.html", session, status=status, nav="tokens",
                          tokens=mine, created=created, message=message)

    @app.post("/tokens")
    async def token_change(request: Request) -> Response:
        session, form, _ = await tools.change(request, "token", Role.VIEWER)
        where = tools.address(request)
        try:
            if form.get("op") == "create":
                text, _ = tokens.create(session.user.name, form.get("name", ""),
                                        _days(form.get("days", "90")), where)
                return tokens_page(request, session, created=text)
            tokens.revoke(int(form.get("id", "0") or 0), session.user, where)
        except (StationAuthError, ValueError) as exc:
            return tokens_page(request, session, message=str(exc), status=400)
        return RedirectResponse("/tokens", status_code=303)


def _days(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"days: not a number: {text[:20]!r}") from None


def alert_context(alerts: AlertService | None) -> dict[str, Any]:
    return {"alerting": alerts is not None}
