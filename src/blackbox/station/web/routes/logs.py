"""Log requests: the list, asking a robot for its log, one request's progress (live) and
its download as JSON lines, CSV or MCAP."""

from __future__ import annotations

import io
from typing import Annotated, Any
from urllib.parse import quote, urlencode

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import RedirectResponse, Response

from blackbox.station.auth import Role
from blackbox.station.web.context import Number, WebContext
from blackbox.station.web.formats import parse_time
from blackbox.station.web.live import Snapshot, StreamQuery

LOG_PAGE, LOG_PAGES = 30, 33
"""Log requests per page of /logs, and how many pages back (the store reads 1,000 at most)."""


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    store = web.store

    def log_state(number: int) -> dict[str, Any]:
        info = store.log_request(number)
        return {} if info is None else {"status": info.status, "rows": info.rows,
                                        "pages": info.pages, "progress": info.progress,
                                        "message": info.message}

    def log_snapshot(query: StreamQuery) -> Snapshot:
        return lambda: log_state(query.id)

    web.live.add("log", log_snapshot)

    @routes.get("/logs")
    async def logs(request: Request, robot: str = "", entity: str = "",
                   page_number: Annotated[int, Query(alias="page", ge=0,
                                                     le=LOG_PAGES - 1)] = 0) -> Response:
        session = web.require(request)
        newest = store.log_requests(limit=(page_number + 1) * LOG_PAGE + 1)
        shown = newest[page_number * LOG_PAGE:(page_number + 1) * LOG_PAGE]
        older = urlencode({"page": page_number + 1}) \
            if len(newest) > (page_number + 1) * LOG_PAGE and page_number + 1 < LOG_PAGES \
            else ""
        return web.page(request, "logs.html", session, requests=shown, older=older,
                        robots=web.robots(), robot=robot, entity=entity, nav="logs")

    @routes.post("/logs")
    async def request_logs(request: Request) -> Response:
        session, form, target = await web.change(request, "logs.request", Role.OPERATOR)
        robot_id = form.get("robot", "")
        since, until = parse_time(form.get("since")), parse_time(form.get("until"))

        def request_them() -> int:
            if not robot_id:
                raise ValueError("choose a robot")
            return web.operations.request_logs(robot_id, entity=form.get("entity") or None,
                                               since=since, until=until,
                                               requested_by=session.user.name)
        number = web.operate(request, session, "logs.request", target, request_them,
                             lambda n: f"request={n} since={since} until={until}")
        return RedirectResponse(f"/logs/{number}", status_code=303)

    @routes.get("/logs/{number}")
    async def log_request(request: Request, number: Number) -> Response:
        session = web.require(request)
        info = store.log_request(number)
        if info is None:
            raise HTTPException(404, "no such log request")
        return web.page(request, "logrequest.html", session, info=info, nav="logs",
                        preview=store.log_entries(number, 0, 20),
                        live=web.live.source("log", id=info.id))

    @routes.get("/logs/{number}/download")
    async def download(request: Request, number: Number, format: str = "jsonl") -> Response:
        web.require(request)
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

    return routes
