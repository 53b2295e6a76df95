"""The fleet page: every robot's status at a glance, live; counts, worst first, filters and
pages for fleets of a thousand robots (the view itself is :mod:`blackbox.station.fleet_view`,
its rows and live state :mod:`blackbox.station.web.fleet_page`)."""

from __future__ import annotations

from urllib.parse import urlencode

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response

from blackbox.station.fleet_view import WORST_FIRST, FleetPage, SiteMap, fleet_page
from blackbox.station.web.context import WebContext
from blackbox.station.web.fleet_page import FleetCache, fleet_state, query_of
from blackbox.station.web.formats import fmt_ago
from blackbox.station.web.live import Snapshot, StreamQuery


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    sites = SiteMap(web.alerts.config.sites if web.alerts is not None else None)
    cache = FleetCache(web.store)

    def fleet_snapshot(query: StreamQuery) -> Snapshot:
        try:
            fleet_query = query_of(dict(query.params))
        except ValueError as exc:
            raise HTTPException(400, str(exc)) from None
        return lambda: fleet_state(cache, sites, fleet_query, fmt_ago)

    web.live.add("fleet", fleet_snapshot)

    @routes.get("/")
    async def fleet(request: Request) -> Response:
        session = web.require(request)
        try:
            query = query_of(dict(request.query_params))
        except ValueError as exc:
            raise HTTPException(400, str(exc)) from None
        view: FleetPage = fleet_page(cache.fleet(), sites.site_of, query)
        links = {
            "older": urlencode(query.params(view.page + 1)) if view.page + 1 < view.pages
            else "",
            "newer": urlencode(query.params(view.page - 1)) if view.page > 0 else None,
            "status": {s: urlencode({**query.params(0), "status": s}) for s in WORST_FIRST},
        }
        return web.page(request, "fleet.html", session, view=view, links=links, nav="fleet",
                        statuses=WORST_FIRST,
                        live=web.live.source("fleet", params=query.params(view.page)))

    return routes
