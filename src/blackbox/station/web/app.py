"""The station's web application: server-rendered pages, live updates over Server-Sent Events.

Pages are Jinja2 templates with autoescaping, so every name a robot sends is shown as text.
The little JavaScript there is (``static/station.js``) only swaps colours and values in
place when the station pushes a change, and writes robot-supplied text with
``textContent``. A Content-Security-Policy allows scripts from this origin only.

Security is in :mod:`blackbox.station.auth`; this module wires it in: every page needs a
session (else a redirect to the log-in page), every POST needs the session's CSRF token,
operators' and admins' actions check the role and are written to the audit table whether
they are allowed or not.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import io
import json
import secrets
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any, Protocol
from urllib.parse import quote, urlencode

from fastapi import FastAPI, HTTPException, Query, Request
from fastapi import Path as UrlPath
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, RedirectResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from markupsafe import Markup
from starlette.middleware.base import BaseHTTPMiddleware

from blackbox.errors import BlackBoxError
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Auth, Role, Session, StationAuthError
from blackbox.station.fleet_view import SiteMap
from blackbox.station.headline import diagnosis_headlines, event_headline, since_words
from blackbox.station.passwords import MAX_PASSWORD
from blackbox.station.store import (
    EVENT_KINDS,
    StationStore,
    StationStoreError,
    UnknownRobot,
)
from blackbox.station.timeline import ZOOMS, Happening, build, svg
from blackbox.station.tokens import ApiTokens
from blackbox.station.web.alerts_pages import PageTools, mount_alert_pages
from blackbox.station.web.api_v1 import create_api
from blackbox.station.web.fleet_page import FleetCache, fleet_router, fleet_state, query_of
from blackbox.station.web.limits import RequestLimits
from blackbox.station.web.metrics import metrics_router
from blackbox.timestamps import parse_timestamp

HERE = Path(__file__).resolve().parent
SESSION_COOKIE = "bb_session"
LOGIN_COOKIE = "bb_login"
CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; "
       "img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'; "
       "form-action 'self'; base-uri 'none'")
HSTS = "max-age=31536000"
"""Sent only on responses served over TLS (a browser ignores it over plain HTTP)."""
MAX_ID = 2**63 - 1
"""The largest number a URL may carry as an id: SQLite's integers are 64-bit."""
Id = Annotated[int, Query(ge=0, le=MAX_ID)]
Number = Annotated[int, UrlPath(ge=0, le=MAX_ID)]
LOG_PAGE, LOG_PAGES = 30, 33
"""Log requests per page of /logs, and how many pages back (the store reads 1,000 at most)."""
EVENT_PAGE = 50
"""Events per page of /events: a page an operator scans without scrolling for long."""


@dataclass(frozen=True, slots=True)
class WebSettings:
    secure_cookies: bool = False
    """Set when served over TLS: cookies then carry ``Secure``."""
    chart_window: float = 300.0
    """Seconds of history in the entity page's charts."""
    sse_heartbeat: float = 15.0


class Operations(Protocol):
    """What the station's DDS follower does for operators (``StationFollower``)."""

    def request_logs(self, robot: str | int, *, entity: str | None = None,
                     characteristic: str | None = None, since: float | None = None,
                     until: float | None = None, kinds: Sequence[str] = (),
                     requested_by: str = "") -> int: ...

    def run_ibit(self, robot: str | int, entity: str = "", requested_by: str = "") -> int: ...


class NotLoggedIn(BlackBoxError):
    """Raised by :func:`require` for a request without a live session."""


def fmt_time(t: float | None) -> str:
    if t is None:
        return "never"
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def fmt_clock(t: float | None) -> str:
    """A table's time: the clock for today (what a glance needs), the date too otherwise;
    the full time is in the cell's title."""
    if t is None:
        return "never"
    at = datetime.fromtimestamp(t, UTC)
    today = at.date() == datetime.now(UTC).date()
    return at.strftime("%H:%M:%S" if today else "%Y-%m-%d %H:%M")


def fmt_ago(t: float | None) -> str:
    if t is None:
        return "never"
    age = max(0.0, time.time() - t)
    if age < 90:
        return f"{age:.0f} s ago"
    if age < 5400:
        return f"{age / 60:.0f} min ago"
    return f"{age / 3600:.1f} h ago"


def fmt_value(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


def parse_time(text: str | None) -> float | None:
    """``YYYY-MM-DDTHH:MM[:SS]`` (UTC, as a datetime-local input sends it) or epoch seconds."""
    if not text:
        return None
    text = text.strip()
    try:
        return parse_timestamp(text)
    except ValueError:
        raise HTTPException(400, f"not a time: {text[:40]!r} (use YYYY-MM-DDTHH:MM:SS, UTC)")\
            from None


class ChangeSignal:
    """Wakes every open live stream when the store commits a change.

    The store calls back on its writing thread; the callback only schedules setting one
    :class:`asyncio.Event` per stream on the event loop, so streams wait without holding a
    worker thread each (a control room may keep many pages open).
    """

    def __init__(self, store: StationStore) -> None:
        self._store = store
        self._events: set[asyncio.Event] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._remove: Callable[[], None] | None = None

    def register(self) -> asyncio.Event:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
            self._remove = self._store.add_listener(self._changed)
        event = asyncio.Event()
        self._events.add(event)
        return event

    def unregister(self, event: asyncio.Event) -> None:
        self._events.discard(event)

    def _changed(self, change: object) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        for event in list(self._events):
            event.set()

    def close(self) -> None:
        if self._remove is not None:
            self._remove()


def robot_ref(robot_id: str, resource_id: int) -> str:
    """How pages name a robot in URLs: its id, else ``#<resource id>``."""
    return robot_id or f"#{resource_id}"


def create_app(auth: Auth, store: StationStore, operations: Operations,
               settings: WebSettings | None = None,
               stop: threading.Event | None = None, alerts: AlertService | None = None,
               metrics_token: str | None = None) -> FastAPI:
    """The web application. ``stop`` ends the live streams (set it before stopping uvicorn).
    ``alerts``: the alerting service (rules page, ``/api/v1``, ``/metrics``)."""
    settings = settings or WebSettings()
    stop = stop or threading.Event()
    app = FastAPI(title="Robot Black Box station", docs_url=None, redoc_url=None,
                  openapi_url=None)
    templates = Jinja2Templates(directory=str(HERE / "templates"))
    env = templates.env
    env.autoescape = True
    env.filters["when"] = fmt_time
    env.filters["ago"] = fmt_ago
    env.filters["clock"] = fmt_clock
    env.filters["value"] = fmt_value
    env.filters["q"] = lambda v: quote(str(v), safe="")
    env.globals["health_class"] = lambda h: "h-" + str(h).lower().replace("_", "-")
    env.globals["ref"] = robot_ref
    env.globals["event_headline"] = lambda ev: event_headline(ev.kind, ev.entity, ev.text,
                                                              ev.details, ev.time)
    env.globals["since_words"] = lambda t: since_words(t, time.time())
    app.mount("/static", StaticFiles(directory=str(HERE / "static")), name="static")

    class Headers(BaseHTTPMiddleware):
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

    app.add_middleware(RequestLimits)  # inside Headers: its 413/415 get the headers too
    app.add_middleware(Headers)

    def address(request: Request) -> str:
        return request.client.host if request.client else "?"

    def session_of(request: Request) -> Session | None:
        return auth.session(request.cookies.get(SESSION_COOKIE))

    def require(request: Request, role: Role = Role.VIEWER) -> Session:
        session = session_of(request)
        if session is None:
            raise NotLoggedIn()
        if session.user.role < role:
            raise HTTPException(403, f"this needs the {role.label} role; you are "
                                f"{session.user.role.label}")
        return session

    async def change(request: Request, action: str,
                     role: Role) -> tuple[Session, dict[str, str], str]:
        """A state-changing request: session, CSRF token and role checked, refusals audited.
        Returns the session, the form and the action's target for the audit."""
        session = session_of(request)
        if session is None:
            raise NotLoggedIn()
        form = {k: v for k, v in (await request.form()).items() if isinstance(v, str)}
        target = ":".join(form.get(k, "")[:200] for k in ("robot", "entity", "name", "event")
                          if form.get(k))
        presented = form.get("csrf_token") or request.headers.get("x-csrf-token")
        if not Auth.csrf_matches(session, presented):
            auth.audit(session.user.name, action, target, "refused", address(request),
                       "missing or wrong CSRF token")
            raise HTTPException(403, "missing or wrong CSRF token; reload the page")
        if session.user.role < role:
            auth.audit(session.user.name, action, target, "refused", address(request),
                       f"needs role {role.label}")
            raise HTTPException(403, f"this needs the {role.label} role; you are "
                                f"{session.user.role.label}")
        return session, form, target

    def operate(request: Request, session: Session, action: str, target: str,
                start: Callable[[], int], detail: Callable[[int], str]) -> int:
        """Start an operator's remote operation and audit it: refused (answered 400) when
        it raises ValueError or LookupError, else ok with ``detail`` of its number."""
        try:
            number = start()
        except (ValueError, LookupError) as exc:
            auth.audit(session.user.name, action, target, "refused", address(request),
                       str(exc))
            raise HTTPException(400, str(exc)) from None
        auth.audit(session.user.name, action, target, "ok", address(request), detail(number))
        return number

    def page(request: Request, name: str, session: Session | None, status: int = 200,
             **context: Any) -> HTMLResponse:
        return templates.TemplateResponse(request, name, {
            "session": session, "user": session.user if session else None,
            "csrf": session.csrf if session else "", "Role": Role,
            "problems": store.problems(5) if session else [], **context},
            status_code=status)

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
        return page(request, "error.html", session_of(request), status=exc.status_code,
                    code=exc.status_code, message=str(exc.detail))

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

    # ---- log-in / log-out ------------------------------------------------------------------

    def login_page(request: Request, message: str = "", status: int = 200,
                   next_url: str = "/") -> Response:
        token = secrets.token_urlsafe(24)
        response = page(request, "login.html", None, status=status, login_token=token,
                        message=message, next_url=next_url)
        response.set_cookie(LOGIN_COOKIE, token, httponly=True, samesite="strict",
                            secure=settings.secure_cookies, max_age=1800, path="/login")
        return response

    def safe_next(target: str | None) -> str:
        if not target or not target.startswith("/") or target.startswith("//") or \
                "\\" in target:
            return "/"
        return target

    @app.get("/login")
    async def login_form(request: Request, next: str = "/") -> Response:
        if session_of(request) is not None:
            return RedirectResponse(safe_next(next), status_code=303)
        return login_page(request, next_url=safe_next(next))

    @app.post("/login")
    async def login(request: Request) -> Response:
        form = {k: v for k, v in (await request.form()).items() if isinstance(v, str)}
        cookie = request.cookies.get(LOGIN_COOKIE, "")
        if not cookie or not hmac.compare_digest(cookie, form.get("login_token", "")):
            auth.audit(form.get("username", "")[:64], "login", "", "refused", address(request),
                       "missing or wrong CSRF token")
            return login_page(request, "The log-in form expired; please try again.", 403)
        name = form.get("username", "")[:64]
        result = await asyncio.to_thread(auth.log_in, name,
                                         form.get("password", "")[:MAX_PASSWORD + 1],
                                         address(request))
        next_url = safe_next(form.get("next"))
        if result.retry_after > 0:
            response = login_page(request, "Too many failed log-ins. Try again in "
                                  f"{result.retry_after:.0f} s.", 429, next_url)
            response.headers["Retry-After"] = str(int(result.retry_after) + 1)
            return response
        if result.session_token is None:
            return login_page(request, "Wrong user name or password.", 401, next_url)
        response = RedirectResponse(next_url, status_code=303)
        response.set_cookie(SESSION_COOKIE, result.session_token, httponly=True,
                            samesite="strict", secure=settings.secure_cookies, path="/",
                            max_age=int(auth.policy.max_age))
        response.delete_cookie(LOGIN_COOKIE, path="/login")
        return response

    @app.post("/logout")
    async def logout(request: Request) -> Response:
        await change(request, "logout", Role.VIEWER)
        auth.log_out(request.cookies.get(SESSION_COOKIE, ""), address(request))
        response = RedirectResponse("/login", status_code=303)
        response.delete_cookie(SESSION_COOKIE, path="/")
        return response

    # ---- pages -----------------------------------------------------------------------------

    sites = SiteMap(alerts.config.sites if alerts is not None else None)
    fleet_cache = FleetCache(store)
    app.include_router(fleet_router(fleet_cache, sites, page, require))  # GET /: fleet_page.py

    def headlines_of(r: str) -> list[Any]:
        """The robot page's headlines: the diagnosis, with each component's latest failure."""
        summary, diagnosis = store.robot(r), store.diagnosis(r)
        failures = {name: (ev.text, ev.details, ev.time) for name in diagnosis.components
                    for ev in store.events(r, entity=name, kinds=["failure"], limit=1).events}
        degraded = [e.name for e in store.entities(r)
                    if e.kind != "robot" and e.status == "DEGRADED"]
        return diagnosis_headlines(summary.name, diagnosis.components, diagnosis.since,
                                   failures, degraded, stale=summary.stale,
                                   online=summary.online)

    def timeline_of(r: str, zoom: str, only: str = "", links: bool = True) -> str:
        """The robot's health timeline over the last ``zoom`` (see station/timeline.py):
        every entity, or ``only`` that one (with the robot's lane)."""
        end = time.time()
        start = end - ZOOMS[zoom if zoom in ZOOMS else "1h"]
        names = [e.name for e in store.entities(r) if e.kind != "robot"
                 and (not only or e.name == only)]
        kinds = ["failure", "rectification", "exceedance"]
        found = store.events(r, kinds=kinds, since=start, until=end, limit=1000).events
        before = {}
        for name in names:
            last = store.events(r, entity=name, kinds=["failure", "rectification"],
                                until=start, limit=1).events
            if last:
                before[name] = "NOT_OPERATIONAL" if last[0].kind == "failure" else \
                    "OPERATIONAL"
        lanes = build(store.robot(r).name, names,
                      [Happening(e.time, e.kind, e.entity, e.acknowledged_at) for e in found],
                      start, end, before)
        return svg(lanes, start, end, robot_ref=r if links else "")

    @app.get("/robot/timeline.svg")
    async def timeline_svg(request: Request, r: str, zoom: str = "1h", entity: str = "",
                           links: bool = False) -> Response:
        """The timeline as a file for an incident report (no links: it stands alone), or
        with ``links`` the page's own picture, redrawn when the robot's state changes."""
        require(request)
        if links:
            return Response(timeline_of(r, zoom, entity), media_type="image/svg+xml")
        name = f"{r}-timeline-{zoom}.svg".replace("/", "_").replace("#", "")
        return Response(timeline_of(r, zoom, entity, links=False), media_type="image/svg+xml",
                        headers={"Content-Disposition":
                                 f"attachment; filename*=UTF-8''{quote(name)}"})

    @app.get("/robot")
    async def robot(request: Request, r: str, zoom: str = "1h") -> Response:
        session = require(request)
        summary = store.robot(r)
        entities = store.entities(r)
        ibits = store.ibit_runs(r, limit=1)
        keys = getattr(operations, "robot_keys", None)  # trust on first use (enrolment.py)
        seen = [k.public_key for k in keys.seen() if k.robot_id == summary.robot_id] \
            if keys is not None and keys.trusted(summary.robot_id) is None else []
        return page(request, "robot.html", session, robot=summary, ref=r, entities=entities,
                    diagnosis=store.diagnosis(r), headlines=headlines_of(r), nav="fleet",
                    zoom=zoom if zoom in ZOOMS else "1h", zooms=list(ZOOMS),
                    timeline=Markup(timeline_of(r, zoom if zoom in ZOOMS else "1h")),
                    events=store.events(r, limit=20).events,
                    last_ibit=ibits[0] if ibits else None, seen_keys=seen)

    @app.post("/robot/enrol")
    async def robot_enrol(request: Request) -> Response:
        """Trust on first use, confirmed by an administrator: enrol the one key seen."""
        from blackbox.station.enrolment import EnrolmentError

        session, form, target = await change(request, "robot.enrol", Role.ADMIN)
        keys = getattr(operations, "robot_keys", None)
        robot_id = form.get("robot", "")[:200]
        try:
            if keys is None:
                raise EnrolmentError("this station keeps no robot keys")
            enrolled = keys.confirm_seen(robot_id)
        except EnrolmentError as exc:
            auth.audit(session.user.name, "robot.enrol", target, "refused", address(request),
                       str(exc))
            raise HTTPException(400, str(exc)) from None
        auth.audit(session.user.name, "robot.enrol", target, "ok", address(request),
                   f"key {enrolled.public_key}")
        return RedirectResponse(f"/robot?r={quote(robot_id, safe='')}", status_code=303)

    @app.get("/entity")
    async def entity(request: Request, r: str, id: Id, zoom: str = "1h") -> Response:
        session = require(request)
        summary = store.robot(r)
        node = store.entity(r, id)
        if node is None:
            raise HTTPException(404, f"robot {r!r} has no entity #{id}")
        chars = store.characteristics(r, id)
        since = time.time() - settings.chart_window
        series = {str(c.instance_id): [[p.time for p in pts], [p.value for p in pts]]
                  for c in chars
                  for pts in [store.series(r, c.instance_id, since=since, max_points=600)]}
        events = store.events(r, entity=node.name, kinds=["failure", "exceedance",
                                                          "rectification", "state_change",
                                                          "ibit"], limit=50).events
        return page(request, "entity.html", session, robot=summary, ref=r, node=node,
                    zoom=zoom if zoom in ZOOMS else "1h", zooms=list(ZOOMS),
                    timeline=Markup(timeline_of(r, zoom, node.name)),
                    characteristics=chars, events=events, nav="fleet",
                    series_json=json.dumps(series), window=settings.chart_window)

    @app.get("/events")
    async def events(request: Request, robot: str = "", entity: str = "", kind: str = "",
                     since: str = "", until: str = "", cursor: str = "") -> Response:
        session = require(request)
        found = store.events(robot or None, entity=entity or None,
                             kinds=[kind] if kind else None, since=parse_time(since),
                             until=parse_time(until), cursor=cursor or None, limit=EVENT_PAGE)
        filters = {"robot": robot, "entity": entity, "kind": kind, "since": since,
                   "until": until}
        more = urlencode({**filters, "cursor": found.next_cursor}) if found.next_cursor \
            else ""
        return page(request, "events.html", session, events=found.events, kinds=EVENT_KINDS,
                    robots=[robot_ref(s.robot_id, s.resource_id) for s in store.fleet()],
                    nav="events", filters=filters, more=more,
                    newest=urlencode(filters) if cursor else "")

    @app.post("/ack")
    async def acknowledge(request: Request) -> Response:
        session, form, target = await change(request, "alarm.ack", Role.OPERATOR)
        try:
            event_id = int(form.get("event", ""))
            if not 0 <= event_id <= MAX_ID:
                raise LookupError(f"no event {event_id}")
            store.acknowledge(event_id, session.user.name, form.get("note", "")[:500])
        except (ValueError, LookupError) as exc:
            auth.audit(session.user.name, "alarm.ack", target, "refused", address(request),
                       str(exc))
            raise HTTPException(404, "no such event to acknowledge") from None
        auth.audit(session.user.name, "alarm.ack", target, "ok", address(request))
        return RedirectResponse(safe_next(form.get("back")), status_code=303)

    @app.get("/logs")
    async def logs(request: Request, robot: str = "", entity: str = "",
                   page_number: Annotated[int, Query(alias="page", ge=0,
                                                     le=LOG_PAGES - 1)] = 0) -> Response:
        session = require(request)
        newest = store.log_requests(limit=(page_number + 1) * LOG_PAGE + 1)
        shown = newest[page_number * LOG_PAGE:(page_number + 1) * LOG_PAGE]
        older = urlencode({"page": page_number + 1}) \
            if len(newest) > (page_number + 1) * LOG_PAGE and page_number + 1 < LOG_PAGES \
            else ""
        return page(request, "logs.html", session, requests=shown, older=older,
                    robots=[robot_ref(s.robot_id, s.resource_id) for s in store.fleet()],
                    robot=robot, entity=entity, nav="logs")

    @app.post("/logs")
    async def request_logs(request: Request) -> Response:
        session, form, target = await change(request, "logs.request", Role.OPERATOR)
        robot_id = form.get("robot", "")
        since, until = parse_time(form.get("since")), parse_time(form.get("until"))

        def request_them() -> int:
            if not robot_id:
                raise ValueError("choose a robot")
            return operations.request_logs(robot_id, entity=form.get("entity") or None,
                                           since=since, until=until,
                                           requested_by=session.user.name)
        number = operate(request, session, "logs.request", target, request_them,
                         lambda n: f"request={n} since={since} until={until}")
        return RedirectResponse(f"/logs/{number}", status_code=303)

    @app.get("/logs/{number}")
    async def log_request(request: Request, number: Number) -> Response:
        session = require(request)
        info = store.log_request(number)
        if info is None:
            raise HTTPException(404, "no such log request")
        return page(request, "logrequest.html", session, info=info, nav="logs",
                    preview=store.log_entries(number, 0, 20))

    @app.get("/logs/{number}/download")
    async def download(request: Request, number: Number, format: str = "jsonl") -> Response:
        require(request)
        info = store.log_request(number)
        if info is None:
            raise HTTPException(404, "no such log request")
        if info.status in ("pending", "running"):
            raise HTTPException(409, f"the log request is still {info.status}")
        if format == "mcap":
            raw = io.BytesIO()
            store.export_log(number, "mcap", raw)
            body, media = raw.getvalue(), "application/octet-stream"
        elif format in ("jsonl", "csv"):
            text = io.StringIO(newline="")
            store.export_log(number, format, text)
            body = text.getvalue().encode()
            media = "application/x-ndjson" if format == "jsonl" else "text/csv"
        else:
            raise HTTPException(400, f"unknown format {format[:20]!r}: jsonl, csv or mcap")
        name = f"{info.robot_id or info.resource_id}-log{number}.{format}".replace("/", "_")
        return Response(body, media_type=media, headers={
            "Content-Disposition": f"attachment; filename*=UTF-8''{quote(name)}"})

    @app.post("/ibit")
    async def ibit(request: Request) -> Response:
        session, form, target = await change(request, "ibit.run", Role.OPERATOR)
        number = operate(request, session, "ibit.run", target,
                         lambda: operations.run_ibit(form.get("robot", ""),
                                                     form.get("entity", ""),
                                                     requested_by=session.user.name),
                         lambda n: f"run={n}")
        return RedirectResponse(f"/ibit/{number}", status_code=303)

    @app.get("/ibit/{number}")
    async def ibit_run(request: Request, number: Number) -> Response:
        session = require(request)
        run = store.ibit_run(number)
        if run is None:
            raise HTTPException(404, "no such built-in test")
        return page(request, "ibit.html", session, run=run, nav="fleet")

    # ---- users (admin) --------------------------------------------------------------------

    @app.get("/users")
    async def users(request: Request) -> Response:
        session = require(request, Role.ADMIN)
        return page(request, "users.html", session, users=auth.users(),
                    audit=auth.audit_log(limit=100), nav="users", message="")

    @app.post("/users")
    async def users_change(request: Request) -> Response:
        session, form, target = await change(request, "user.change", Role.ADMIN)
        op, name = form.get("op", ""), form.get("name", "")[:64]
        by, where = session.user.name, address(request)
        try:
            if op == "add":
                await asyncio.to_thread(auth.add_user, name, form.get("password", ""),
                                        Role.parse(form.get("role", "")), by=by,
                                        address=where)
            elif op == "role":
                auth.set_role(name, Role.parse(form.get("role", "")), by=by, address=where)
            elif op == "password":
                await asyncio.to_thread(auth.set_password, name, form.get("password", ""),
                                        by=by, address=where)
            elif op == "remove":
                if name == by:
                    raise StationAuthError("you cannot remove yourself")
                auth.remove_user(name, by=by, address=where)
            else:
                raise StationAuthError(f"unknown operation {op[:20]!r}")
        except (StationAuthError, ValueError) as exc:
            auth.audit(by, f"user.{op[:20]}", target, "refused", where, str(exc))
            return page(request, "users.html", session, users=auth.users(), status=400,
                        audit=auth.audit_log(limit=100), nav="users", message=str(exc))
        return RedirectResponse("/users", status_code=303)

    # ---- alerting, /api/v1, /metrics (their own modules) ------------------------------------
    tokens = ApiTokens(auth.path, auth)
    mount_alert_pages(app, PageTools(page, require, change, address), alerts, tokens)
    app.mount("/api/v1", create_api(auth, tokens, store, operations, alerts))
    app.include_router(metrics_router(store, alerts, metrics_token,
                                      getattr(operations, "delivery", None)))

    # ---- live updates ---------------------------------------------------------------------

    changes = ChangeSignal(store)

    def robot_state(r: str) -> dict[str, Any]:
        summary = store.robot(r)
        diagnosis = store.diagnosis(r)
        now = time.time()
        return {"status": summary.status, "stale": summary.stale,
                "last_heard": fmt_ago(summary.last_heard),
                "diagnosis": ", ".join(diagnosis.components),
                "explanation": diagnosis.explanation,
                "entities": {str(e.instance_id): e.status for e in store.entities(r)},
                "headlines": [h.to_dict(now) for h in headlines_of(r)],
                "events": [{"id": ev.id, "time": fmt_time(ev.time),
                            "clock": fmt_clock(ev.time), "robot": ev.robot_id,
                            "entity": ev.entity, "kind": ev.kind, "origin": ev.origin,
                            "text": ev.text, "acknowledged_by": ev.acknowledged_by,
                            "headline": event_headline(ev.kind, ev.entity, ev.text,
                                                       ev.details, ev.time).to_dict(now)}
                           for ev in store.events(r, limit=20).events]}

    def entity_state(r: str, iid: int) -> dict[str, Any]:
        node = store.entity(r, iid)
        return {"status": node.status if node else "UNKNOWN",
                "values": {str(c.instance_id): [c.time, c.value, c.exceeded]
                           for c in store.characteristics(r, iid)}}

    def ibit_state(number: int) -> dict[str, Any]:
        run = store.ibit_run(number)
        return {} if run is None else {"status": run.status, "health": run.health,
                                       "observations": run.observations, "failed": run.failed,
                                       "report": list(run.report)}

    def log_state(number: int) -> dict[str, Any]:
        info = store.log_request(number)
        return {} if info is None else {"status": info.status, "rows": info.rows,
                                        "pages": info.pages, "progress": info.progress,
                                        "message": info.message}

    @app.get("/api/stream")
    async def stream(request: Request, view: str = "fleet", r: str = "",
                     id: Id = 0) -> Response:
        session = require(request)
        token = request.cookies.get(SESSION_COOKIE)
        fleet_query = query_of(dict(request.query_params))

        def still_allowed() -> bool:
            """The session is still open with the role it had (not logged out, expired,
            removed, re-passworded or re-roled): checked at every wake of the stream."""
            now = auth.session(token, touch=False)
            return now is not None and now.user.role == session.user.role
        snapshots: dict[str, Callable[[], dict[str, Any]]] = {
            "fleet": lambda: fleet_state(fleet_cache, sites, fleet_query, fmt_ago),
            "robot": lambda: robot_state(r),
            "entity": lambda: entity_state(r, id), "ibit": lambda: ibit_state(id),
            "log": lambda: log_state(id)}
        if view not in snapshots:
            raise HTTPException(400, "unknown view")
        snapshot = snapshots[view]
        snapshot()  # an unknown robot or a bad id is an error answer, not a broken stream

        async def events() -> AsyncIterator[str]:
            wake = changes.register()
            try:
                async for chunk in stream_events(wake):
                    yield chunk
            finally:
                changes.unregister(wake)

        async def stream_events(wake: asyncio.Event) -> AsyncIterator[str]:
            seq = -1
            last_sent = ""
            last_beat = last_look = time.monotonic()
            yield "retry: 1000\n\n"
            while not stop.is_set():
                if not still_allowed() or await request.is_disconnected():
                    break
                current = store.sequence
                if current != seq or time.monotonic() - last_look > 2.0:  # staleness ages
                    seq = current
                    last_look = time.monotonic()
                    try:
                        text = json.dumps(snapshot())
                    except (LookupError, OverflowError):
                        text = "{}"
                    if text != last_sent:
                        last_sent = text
                        last_beat = time.monotonic()
                        yield f"event: state\ndata: {text}\n\n"
                        continue
                if time.monotonic() - last_beat > settings.sse_heartbeat:
                    last_beat = time.monotonic()
                    yield ": beat\n\n"
                wake.clear()
                if store.sequence == seq:
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(wake.wait(), 0.5)
            yield "event: end\ndata: {}\n\n"

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store",
                                          "X-Accel-Buffering": "no"})

    return app
