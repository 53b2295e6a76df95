"""The station's web application: server-rendered pages, live updates over Server-Sent Events.

Pages are Jinja2 templates with autoescaping, so every name a robot sends is shown as text.
The little JavaScript there is (``static/station.js``) only swaps colours and values in
place when the station pushes a change, and writes robot-supplied text with
``textContent``. A Content-Security-Policy allows scripts from this origin only.

This module only assembles the application: security headers, error pages, and the list of
page routers (:data:`PAGES`, one module per page group in ``web/routes/``), each given the
shared :class:`~blackbox.station.web.context.WebContext` (session, CSRF, roles, audit,
templates, the table of live views). Security is in :mod:`blackbox.station.auth`.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Awaitable, Callable
from urllib.parse import urlencode

from fastapi import APIRouter, FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import RedirectResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.middleware.base import BaseHTTPMiddleware

from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Auth
from blackbox.station.store import StationStore, StationStoreError, UnknownRobot
from blackbox.station.tokens import ApiTokens
from blackbox.station.web.alerts_pages import PageTools, mount_alert_pages
from blackbox.station.web.api_v1 import create_api
from blackbox.station.web.context import (
    HERE,
    NotLoggedIn,
    Operations,
    WebContext,
    WebSettings,
)
from blackbox.station.web.limits import RequestLimits
from blackbox.station.web.live import ChangeSignal
from blackbox.station.web.metrics import metrics_router
from blackbox.station.web.routes import (
    admin,
    entity,
    events,
    fleet,
    ibit,
    login,
    logs,
    moment,
    robot,
    stream,
)

__all__ = ["PAGES", "Operations", "WebSettings", "create_app"]

CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; "
       "img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'; "
       "form-action 'self'; base-uri 'none'")
HSTS = "max-age=31536000"
"""Sent only on responses served over TLS (a browser ignores it over plain HTTP)."""

PAGES: tuple[Callable[[WebContext], APIRouter], ...] = (
    login.router, fleet.router, robot.router, entity.router, events.router, logs.router,
    ibit.router, admin.router, moment.router)
"""The page groups, in the order their routes are matched: a new page is one line here."""


class Headers(BaseHTTPMiddleware):
    """Security headers on every answer, pages and errors alike."""

    async def dispatch(self, request: Request,
                       call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        response = await call_next(request)
        response.headers.setdefault("Content-Security-Policy", CSP)
        response.headers["X-Content-Type-Options"] = "nosniff"
        response.headers["Referrer-Policy"] = "same-origin"
        response.headers["X-Frame-Options"] = "DENY"
        if not request.url.path.startswith("/static"):
            response.headers["Cache-Control"] = "no-store"
        if request.url.scheme == "https":
            response.headers["Strict-Transport-Security"] = HSTS
        return response


def create_app(auth: Auth, store: StationStore, operations: Operations,
               settings: WebSettings | None = None,
               stop: threading.Event | None = None, alerts: AlertService | None = None,
               metrics_token: str | None = None) -> FastAPI:
    """The web application. ``stop`` ends the live streams (set it before stopping uvicorn).
    ``alerts``: the alerting service (rules page, ``/api/v1``, ``/metrics``)."""
    web = WebContext(auth, store, operations, settings or WebSettings(),
                     stop or threading.Event(), alerts)
    app = FastAPI(title="Robot Black Box station", docs_url=None, redoc_url=None,
                  openapi_url=None)
    app.mount("/static", StaticFiles(directory=str(HERE / "static")), name="static")
    app.add_middleware(RequestLimits)  # inside Headers: its 413/415 get the headers too
    app.add_middleware(Headers)
    add_error_pages(app, web)
    for page_group in PAGES:
        app.include_router(page_group(web))
    app.state.live = web.live  # the one table of live views (tests read it)
    tokens = ApiTokens(auth.path, auth)
    mount_alert_pages(app, PageTools(web.page, web.require, web.change, web.address),
                      alerts, tokens)
    app.mount("/api/v1", create_api(auth, tokens, store, operations, alerts))
    app.include_router(metrics_router(store, alerts, metrics_token,
                                      getattr(operations, "delivery", None)))
    app.include_router(stream.router(web, ChangeSignal(store)))
    return app


def add_error_pages(app: FastAPI, web: WebContext) -> None:
    """Errors as pages (JSON under ``/api/``); no session: to the log-in page."""

    @app.exception_handler(NotLoggedIn)
    async def to_login(request: Request, exc: NotLoggedIn) -> Response:
        if request.url.path.startswith("/api/") or request.method != "GET":
            return Response("log in first\n", status_code=401, media_type="text/plain")
        target = request.url.path + (f"?{request.url.query}" if request.url.query else "")
        return RedirectResponse("/login?" + urlencode({"next": target}), status_code=303)

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> Response:
        if request.url.path.startswith("/api/"):
            return Response(json.dumps({"error": exc.detail}), status_code=exc.status_code,
                            media_type="application/json")
        try:
            session = web.session_of(request)
        except StationStoreError:  # the database is away: say so without the session
            session = None
        return web.page(request, "error.html", session,
                        status=exc.status_code, code=exc.status_code, message=str(exc.detail))

    @app.exception_handler(UnknownRobot)
    async def unknown_robot(request: Request, exc: UnknownRobot) -> Response:
        return await http_error(request, HTTPException(404, str(exc)))

    @app.exception_handler(StationStoreError)
    async def store_error(request: Request, exc: StationStoreError) -> Response:
        return await http_error(request, HTTPException(503, str(exc)))

    @app.exception_handler(ValueError)
    async def bad_value(request: Request, exc: ValueError) -> Response:
        return await http_error(request, HTTPException(400, str(exc)))

    @app.exception_handler(OverflowError)
    async def out_of_range(request: Request, exc: OverflowError) -> Response:
        return await http_error(request, HTTPException(400, "a number is out of range"))

    @app.exception_handler(RequestValidationError)
    async def bad_parameter(request: Request, exc: RequestValidationError) -> Response:
        problems = "; ".join(f"{'.'.join(str(p) for p in e.get('loc', ())[1:])}: "
                             f"{e.get('msg', 'invalid')}" for e in exc.errors()[:3])
        return await http_error(request, HTTPException(400, problems[:300] or "bad request"))
