"""The entity page: one entity's status, characteristics with charts, timeline and events."""

from __future__ import annotations

import json
import time
from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response
from markupsafe import Markup

from blackbox.station.timeline import ZOOMS
from blackbox.station.web.context import Id, WebContext
from blackbox.station.web.health_timeline import timeline_of
from blackbox.station.web.live import Snapshot, StreamQuery


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    store, settings = web.store, web.settings

    def entity_state(r: str, iid: int) -> dict[str, Any]:
        node = store.entity(r, iid)
        return {"status": node.status if node else "UNKNOWN",
                "values": {str(c.instance_id): [c.time, c.value, c.exceeded]
                           for c in store.characteristics(r, iid)}}

    def entity_snapshot(query: StreamQuery) -> Snapshot:
        return lambda: entity_state(query.r, query.id)

    web.live.add("entity", entity_snapshot)

    @routes.get("/entity")
    async def entity(request: Request, r: str, id: Id, zoom: str = "1h") -> Response:
        session = web.require(request)
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
        return web.page(request, "entity.html", session, robot=summary, ref=r, node=node,
                        zoom=zoom if zoom in ZOOMS else "1h", zooms=list(ZOOMS),
                        timeline=Markup(timeline_of(store, r, zoom, node.name)),
                        characteristics=chars, events=events, nav="fleet",
                        series_json=json.dumps(series), window=settings.chart_window,
                        live=web.live.source("entity", r=r, id=node.instance_id))

    return routes
