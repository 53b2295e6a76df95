"""``/api/v1``: the station's versioned REST API, described by ``/api/v1/openapi.json``.

For the tools a fleet team already runs (dashboards, ticketing, on-call bots). Every call
needs ``Authorization: Bearer <API token>`` (:mod:`blackbox.station.tokens`), never the
page's session cookie, and is held to the same roles as the page: viewers read, operators
acknowledge and ask robots for logs and built-in tests, admins change alert rules. Every
change is audited like the page's. Request bodies are bounded (:data:`MAX_BODY`); errors
are JSON ``{"error": ...}`` with the status code that says what went wrong.
"""


import asyncio
import io
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Protocol

from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from blackbox.station.alerts.engine import Alert, AlertRuleError
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Auth, Role, User
from blackbox.station.store import (
    Diagnosis,
    EntityNode,
    Event,
    EventPage,
    IbitRun,
    LogRequest,
    RobotSummary,
    StationStore,
    StationStoreError,
    UnknownRobot,
)
from blackbox.station.tokens import ApiTokens

MAX_BODY = 64 * 1024


class Operations(Protocol):
    def request_logs(self, robot: str | int, *, entity: str | None = None,
                     characteristic: str | None = None, since: float | None = None,
                     until: float | None = None, kinds: Sequence[str] = (),
                     requested_by: str = "") -> int: ...

    def run_ibit(self, robot: str | int, entity: str = "", requested_by: str = "") -> int: ...


@dataclass(frozen=True, slots=True)
class RobotDetail:
    robot: RobotSummary
    entities: list[EntityNode]
    diagnosis: Diagnosis


@dataclass(frozen=True, slots=True)
class RuleOut:
    name: str
    source: str
    send: list[str]
    text: str


class AckBody(BaseModel):
    note: str = Field("", max_length=500)


class LogBody(BaseModel):
    robot: str = Field(min_length=1, max_length=200)
    entity: str | None = Field(None, max_length=200)
    since: float | None = None
    until: float | None = None


class IbitBody(BaseModel):
    robot: str = Field(min_length=1, max_length=200)
    entity: str = Field("", max_length=200)


class RuleBody(BaseModel):
    yaml: str = Field(min_length=1, max_length=20_000)


class Error(BaseModel):
    error: str


ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": Error}, 401: {"model": Error}, 403: {"model": Error},
    404: {"model": Error}, 413: {"model": Error}, 422: {"model": Error}}


def create_api(auth: Auth, tokens: ApiTokens, store: StationStore, operations: Operations,
               alerts: AlertService | None) -> FastAPI:
    api = FastAPI(title="Robot Black Box station API", version="1", docs_url=None,
                  redoc_url=None, openapi_url="/openapi.json", responses=ERRORS)

    @api.middleware("http")
    async def bounded(request: Request,
                      call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        length = request.headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > MAX_BODY):
            return JSONResponse({"error": f"request body over {MAX_BODY} bytes"}, 413)
        if request.headers.get("transfer-encoding", "").lower() == "chunked":
            return JSONResponse({"error": "send a Content-Length, not a chunked body"}, 411)
        return await call_next(request)

    @api.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> Response:
        return JSONResponse({"error": exc.detail}, exc.status_code, headers=exc.headers)

    @api.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> Response:
        first = exc.errors()[0] if exc.errors() else {}
        where = ".".join(str(p) for p in first.get("loc", ()))
        return JSONResponse({"error": f"{where}: {first.get('msg', 'invalid request')}"[:300]},
                            422)

    @api.exception_handler(UnknownRobot)
    async def unknown(request: Request, exc: UnknownRobot) -> Response:
        return JSONResponse({"error": str(exc)}, 404)

    @api.exception_handler(StationStoreError)
    async def store_error(request: Request, exc: StationStoreError) -> Response:
        return JSONResponse({"error": str(exc)}, 503)

    @api.exception_handler(ValueError)
    async def bad_value(request: Request, exc: ValueError) -> Response:
        return JSONResponse({"error": str(exc)[:300]}, 400)

    def address(request: Request) -> str:
        return request.client.host if request.client else "?"

    def needs(role: Role) -> Callable[[Request], User]:
        def check(request: Request) -> User:
            header = request.headers.get("authorization", "")
            scheme, _, presented = header.partition(" ")
            user = tokens.user_of(presented.strip()) if scheme.lower() == "bearer" else None
            if user is None:
                raise HTTPException(401, "an API token is needed (Authorization: Bearer "
                                    "bbt_...); it may have expired or been revoked",
                                    headers={"WWW-Authenticate": "Bearer"})
            if user.role < role:
                auth.audit(user.name, f"api {request.method} {request.url.path}"[:100], "",
                           "refused", address(request), f"needs role {role.label}")
                raise HTTPException(403, f"this needs the {role.label} role; the token's "
                                    f"user is {user.role.label}")
            return user
        return check

    Viewer = Annotated[User, Depends(needs(Role.VIEWER))]
    Operator = Annotated[User, Depends(needs(Role.OPERATOR))]
    Admin = Annotated[User, Depends(needs(Role.ADMIN))]

    def engine() -> AlertService:
        if alerts is None:
            raise HTTPException(404, "alerting is not enabled on this station")
        return alerts

    @api.get("/fleet", response_model=list[RobotSummary], summary="Every robot's state")
    def fleet(user: Viewer) -> list[RobotSummary]:
        return store.fleet()

    @api.get("/robots/{robot}", response_model=RobotDetail,
             summary="One robot: state, entity tree, diagnosis")
    def robot(robot: str, user: Viewer) -> RobotDetail:
        return RobotDetail(store.robot(robot), store.entities(robot), store.diagnosis(robot))

    @api.get("/events", response_model=EventPage, summary="Events newest first, with paging")
    def events(user: Viewer, robot: str | None = None, entity: str | None = None,
               kind: Annotated[list[str] | None, Query()] = None, since: float | None = None,
               until: float | None = None, unacknowledged: bool = False,
               cursor: str | None = None,
               limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> EventPage:
        return store.events(robot, entity=entity, kinds=kind, since=since, until=until,
                            unacknowledged=unacknowledged, cursor=cursor, limit=limit)

    @api.post("/events/{event_id}/ack", response_model=Event, summary="Acknowledge an event")
    def ack_event(event_id: int, body: AckBody, user: Operator, request: Request) -> Event:
        try:
            event = store.acknowledge(event_id, user.name, body.note)
        except LookupError:
            auth.audit(user.name, "alarm.ack", str(event_id), "refused", address(request),
                       "no such event (api)")
            raise HTTPException(404, f"no event {event_id}") from None
        auth.audit(user.name, "alarm.ack", str(event_id), "ok", address(request), "api")
        return event

    def operate(user: User, request: Request, action: str, target: str,
                start: Callable[[], int]) -> int:
        try:
            number = start()
        except (ValueError, LookupError) as exc:
            auth.audit(user.name, action, target, "refused", address(request), str(exc))
            raise HTTPException(400, str(exc)) from None
        auth.audit(user.name, action, target, "ok", address(request), f"api number={number}")
        return number

    @api.post("/logs", response_model=LogRequest, status_code=201,
              summary="Ask a robot for its log")
    def request_logs(body: LogBody, user: Operator, request: Request) -> LogRequest:
        number = operate(user, request, "logs.request", body.robot, lambda: (
            operations.request_logs(body.robot, entity=body.entity, since=body.since,
                                    until=body.until, requested_by=user.name)))
        info = store.log_request(number)
        assert info is not None
        return info

    @api.get("/logs/{number}", response_model=LogRequest, summary="A log request's progress")
    def log_request(number: int, user: Viewer) -> LogRequest:
        info = store.log_request(number)
        if info is None:
            raise HTTPException(404, f"no log request {number}")
        return info

    @api.get("/logs/{number}/download", summary="A finished log (jsonl, csv or mcap)",
             responses={200: {"content": {"application/x-ndjson": {}, "text/csv": {},
                                          "application/octet-stream": {}}},
                        409: {"model": Error}})
    def download(number: int, user: Viewer, format: str = "jsonl") -> Response:
        info = store.log_request(number)
        if info is None:
            raise HTTPException(404, f"no log request {number}")
        if info.status in ("pending", "running"):
            raise HTTPException(409, f"the log request is still {info.status}")
        if format not in ("jsonl", "csv", "mcap"):
            raise HTTPException(400, f"unknown format {format[:20]!r}: jsonl, csv or mcap")
        raw: Any = io.BytesIO() if format == "mcap" else io.StringIO(newline="")
        store.export_log(number, format, raw)
        body = raw.getvalue()
        media = {"jsonl": "application/x-ndjson", "csv": "text/csv",
                 "mcap": "application/octet-stream"}[format]
        return Response(body if isinstance(body, bytes) else body.encode(), media_type=media)

    @api.post("/ibit", response_model=IbitRun, status_code=201,
              summary="Run a robot's built-in test")
    def ibit(body: IbitBody, user: Operator, request: Request) -> IbitRun:
        number = operate(user, request, "ibit.run", body.robot, lambda: (
            operations.run_ibit(body.robot, body.entity, requested_by=user.name)))
        run = store.ibit_run(number)
        assert run is not None
        return run

    @api.get("/ibit/{number}", response_model=IbitRun, summary="A built-in test's result")
    def ibit_run(number: int, user: Viewer) -> IbitRun:
        run = store.ibit_run(number)
        if run is None:
            raise HTTPException(404, f"no built-in test {number}")
        return run

    @api.get("/alerts", response_model=list[Alert], summary="Alerts, newest first")
    def list_alerts(user: Viewer, state: str | None = None,
                    limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[Alert]:
        return engine().engine.alerts(state=state, limit=limit)

    @api.post("/alerts/{alert_id}/ack", response_model=Alert,
              summary="Acknowledge an alert (stops its escalation)")
    async def ack_alert(alert_id: int, body: AckBody, user: Operator) -> Alert:
        service = engine()
        try:
            alert = await asyncio.to_thread(service.engine.acknowledge, alert_id, user.name,
                                            service.clock(), "api")
        except LookupError:
            raise HTTPException(404, f"no alert {alert_id}") from None
        service.wake()
        return alert

    def rule_out(name: str) -> RuleOut:
        rule = engine().engine.rule(name)
        if rule is None:
            raise HTTPException(404, f"no rule {name!r}")
        return RuleOut(rule.name, rule.source, list(rule.channels), rule.text)

    @api.get("/alerts/rules", response_model=list[RuleOut], summary="The alert rules")
    def rules(user: Viewer) -> list[RuleOut]:
        return [rule_out(r.name) for r in engine().engine.rules]

    @api.post("/alerts/rules", response_model=RuleOut, status_code=201,
              summary="Add a rule (YAML, as in the alerts file)")
    def add_rule(body: RuleBody, user: Admin) -> RuleOut:
        service = engine()
        try:
            rule = service.engine.add_rule(body.yaml, user.name, service.clock())
        except AlertRuleError as exc:
            raise HTTPException(400, str(exc)) from None
        return rule_out(rule.name)

    @api.delete("/alerts/rules/{name}", status_code=204, summary="Remove a page rule")
    def remove_rule(name: str, user: Admin) -> Response:
        try:
            engine().engine.remove_rule(name, user.name)
        except AlertRuleError as exc:
            raise HTTPException(404, str(exc)) from None
        return Response(status_code=204)

    @api.post("/alerts/rules/{name}/test", summary="Send a test notification of a rule")
    def test_rule(name: str, user: Admin) -> dict[str, list[int]]:
        service = engine()
        try:
            ids = service.engine.send_test(name, user.name, service.clock())
        except AlertRuleError as exc:
            raise HTTPException(404, str(exc)) from None
        service.wake()
        return {"outbox": ids}

    @api.get("/alerts/unmatched", summary="Events of the last hours that matched no rule")
    def unmatched(user: Viewer,
                  hours: Annotated[float, Query(gt=0, le=168)] = 1.0) -> dict[str, int]:
        service = engine()
        return service.engine.unmatched(service.clock() - hours * 3600)

    return api
