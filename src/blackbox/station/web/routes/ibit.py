"""Built-in tests: starting one on a robot or entity and following its run (live)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import RedirectResponse, Response

from blackbox.station.auth import Role
from blackbox.station.web.context import Number, WebContext
from blackbox.station.web.live import Snapshot, StreamQuery


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    store = web.store

    def ibit_state(number: int) -> dict[str, Any]:
        run = store.ibit_run(number)
        return {} if run is None else {"status": run.status, "health": run.health,
                                       "observations": run.observations, "failed": run.failed,
                                       "report": list(run.report)}

    def ibit_snapshot(query: StreamQuery) -> Snapshot:
        return lambda: ibit_state(query.id)

    web.live.add("ibit", ibit_snapshot)

    @routes.post("/ibit")
    async def ibit(request: Request) -> Response:
        session, form, target = await web.change(request, "ibit.run", Role.OPERATOR)
        number = web.operate(request, session, "ibit.run", target,
                             lambda: web.operations.run_ibit(form.get("robot", ""),
                                                             form.get("entity", ""),
                                                             requested_by=session.user.name),
                             lambda n: f"run={n}")
        return RedirectResponse(f"/ibit/{number}", status_code=303)

    @routes.get("/ibit/{number}")
    async def ibit_run(request: Request, number: Number) -> Response:
        session = web.require(request)
        run = store.ibit_run(number)
        if run is None:
            raise HTTPException(404, "no such built-in test")
        return web.page(request, "ibit.html", session, run=run, nav="fleet",
                        live=web.live.source("ibit", id=run.id))

    return routes
