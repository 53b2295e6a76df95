"""What every page of the station shares: the store, the signed-in user, the templates,
CSRF-checked changes with their audit, and the table of live views.

Each router module (``web/routes/``) receives one :class:`WebContext` and holds its pages
to exactly these rules: a page needs a session (else a redirect to the log-in page), a POST
needs the session's CSRF token, and operators' and admins' actions check the role and are
written to the audit table whether they are allowed or not.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Protocol
from urllib.parse import quote

from fastapi import HTTPException, Query, Request
from fastapi import Path as UrlPath
from fastapi.responses import HTMLResponse
from fastapi.templating import Jinja2Templates

from blackbox.errors import BlackBoxError
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Auth, Role, Session
from blackbox.station.headline import event_headline, since_words
from blackbox.station.store import StationStore
from blackbox.station.web.formats import fmt_ago, fmt_clock, fmt_time, fmt_value, robot_ref
from blackbox.station.web.live import LiveViews

HERE = Path(__file__).resolve().parent
SESSION_COOKIE = "bb_session"
LOGIN_COOKIE = "bb_login"
MAX_ID = 2**63 - 1
"""The largest number a URL may carry as an id: SQLite's integers are 64-bit."""
Id = Annotated[int, Query(ge=0, le=MAX_ID)]
Number = Annotated[int, UrlPath(ge=0, le=MAX_ID)]


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
    """Raised by :meth:`WebContext.require` for a request without a live session."""


def make_templates() -> Jinja2Templates:
    """The pages' templates: autoescaped (every name a robot sends is shown as text)."""
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
    return templates


@dataclass(slots=True)
class WebContext:
    auth: Auth
    store: StationStore
    operations: Operations
    settings: WebSettings
    stop: threading.Event
    alerts: AlertService | None = None
    templates: Jinja2Templates = field(default_factory=make_templates)
    live: LiveViews = field(default_factory=LiveViews)

    @staticmethod
    def address(request: Request) -> str:
        return request.client.host if request.client else "?"

    def session_of(self, request: Request) -> Session | None:
        return self.auth.session(request.cookies.get(SESSION_COOKIE))

    def require(self, request: Request, role: Role = Role.VIEWER) -> Session:
        session = self.session_of(request)
        if session is None:
            raise NotLoggedIn()
        if session.user.role < role:
            raise HTTPException(403, f"this needs the {role.label} role; you are "
                                f"{session.user.role.label}")
        return session

    async def change(self, request: Request, action: str,
                     role: Role) -> tuple[Session, dict[str, str], str]:
        """A state-changing request: session, CSRF token and role checked, refusals audited.
        Returns the session, the form and the action's target for the audit."""
        session = self.session_of(request)
        if session is None:
            raise NotLoggedIn()
        form = {k: v for k, v in (await request.form()).items() if isinstance(v, str)}
        target = ":".join(form.get(k, "")[:200] for k in ("robot", "entity", "name", "event")
                          if form.get(k))
        presented = form.get("csrf_token") or request.headers.get("x-csrf-token")
        if not Auth.csrf_matches(session, presented):
            self.auth.audit(session.user.name, action, target, "refused",
                            self.address(request), "missing or wrong CSRF token")
            raise HTTPException(403, "missing or wrong CSRF token; reload the page")
        if session.user.role < role:
            self.auth.audit(session.user.name, action, target, "refused",
                            self.address(request), f"needs role {role.label}")
            raise HTTPException(403, f"this needs the {role.label} role; you are "
                                f"{session.user.role.label}")
        return session, form, target

    def operate(self, request: Request, session: Session, action: str, target: str,
                start: Callable[[], int], detail: Callable[[int], str]) -> int:
        """Start an operator's remote operation and audit it: refused (answered 400) when
        it raises ValueError or LookupError, else ok with ``detail`` of its number."""
        try:
            number = start()
        except (ValueError, LookupError) as exc:
            self.auth.audit(session.user.name, action, target, "refused",
                            self.address(request), str(exc))
            raise HTTPException(400, str(exc)) from None
        self.auth.audit(session.user.name, action, target, "ok", self.address(request),
                        detail(number))
        return number

    def page(self, request: Request, name: str, session: Session | None, status: int = 200,
             **context: Any) -> HTMLResponse:
        return self.templates.TemplateResponse(request, name, {
            "session": session, "user": session.user if session else None,
            "csrf": session.csrf if session else "", "Role": Role,
            "problems": self.store.problems(5) if session else [], **context},
            status_code=status)

    def robots(self) -> list[str]:
        """Every robot's reference, for a page's robot filter."""
        return [robot_ref(s.robot_id, s.resource_id) for s in self.store.fleet()]


def safe_next(target: str | None) -> str:
    """Where to go after logging in or acting: a path on this station, never elsewhere."""
    if not target or not target.startswith("/") or target.startswith("//") or \
            "\\" in target:
        return "/"
    return target
