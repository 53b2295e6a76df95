"""The fleet page: every robot's status at a glance, live."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import Response

from blackbox.station.web.context import WebContext
from blackbox.station.web.formats import fmt_ago, robot_ref
from blackbox.station.web.live import Snapshot, StreamQuery


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    store = web.store

    def fleet_state() -> dict[str, Any]:
        return {"robots": {robot_ref(s.robot_id, s.resource_id): {
            "status": s.status, "stale": s.stale, "last_heard": fmt_ago(s.last_heard),
            "failing": s.failing, "entities": s.entities, "unacknowledged": s.unacknowledged,
            "silent": "silent" if s.stale else ("stopped" if not s.online else ""),
            "diagnosis": ", ".join(s.diagnosis)}
            for s in store.fleet()}}

    def fleet_snapshot(query: StreamQuery) -> Snapshot:
        return fleet_state

    web.live.add("fleet", fleet_snapshot)

    @routes.get("/")
    async def fleet(request: Request) -> Response:
        session = web.require(request)
        return web.page(request, "fleet.html", session, robots=store.fleet(), nav="fleet",
                        live=web.live.source("fleet"))

    return routes
