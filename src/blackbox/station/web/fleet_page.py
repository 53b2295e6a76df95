"""The fleet page (``GET /``) and its live state: counts, worst first, filters, pages.

Its own module so that the page's route and the state its live stream sends are built from
one :class:`~blackbox.station.fleet_view.FleetPage`: the rows the browser redraws are the
rows the server would render for the same query.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlencode

from fastapi import APIRouter, Request
from fastapi.responses import Response

from blackbox.station.fleet_view import WORST_FIRST, FleetPage, FleetQuery, SiteMap, fleet_page
from blackbox.station.store import RobotSummary, StationStore

PageRenderer = Callable[..., Response]
Requirer = Callable[[Request], Any]


class FleetCache:
    """The store's fleet summary, shared by the page and every open live stream for up to
    ``max_age`` seconds while the store has committed nothing new: with 1,000 robots one
    summary costs a good part of the page's time, and a control room keeps many pages open."""

    def __init__(self, store: StationStore, max_age: float = 1.0) -> None:
        self.store = store
        self.max_age = max_age
        self._lock = threading.Lock()
        self._key: tuple[int, float] = (-1, -1.0)
        self._fleet: list[RobotSummary] = []

    def fleet(self) -> list[RobotSummary]:
        with self._lock:
            sequence, now = self.store.sequence, time.monotonic()
            if sequence != self._key[0] or now - self._key[1] > self.max_age:
                self._fleet = self.store.fleet()
                self._key = (sequence, now)
            return self._fleet


def robot_ref(robot_id: str, resource_id: int) -> str:
    """How pages name a robot in URLs: its id, else ``#<resource id>``."""
    return robot_id or f"#{resource_id}"


def query_of(params: dict[str, str]) -> FleetQuery:
    """The fleet query of a request's (or a stream's) parameters."""
    page = params.get("page", "0")
    if not page.isdigit() or len(page) > 6:
        raise ValueError(f"not a page number: {page[:20]!r}")
    return FleetQuery.of(params.get("search", ""), params.get("site", ""),
                         params.get("status", ""), int(page))


def fleet_state(store: FleetCache, sites: SiteMap, query: FleetQuery,
                ago: Callable[[float | None], str]) -> dict[str, Any]:
    """What the page's live stream sends: the counts and the page's rows, in order."""
    view = fleet_page(store.fleet(), sites.site_of, query)
    return {"counts": dict(view.counts), "matched": view.matched, "total": view.total,
            "rows": [{"ref": robot_ref(r.robot.robot_id, r.robot.resource_id),
                      "name": r.robot.name, "site": r.site or "-",
                      "status": r.robot.status, "stale": r.robot.stale,
                      "last_heard": ago(r.robot.last_heard), "failing": r.robot.failing,
                      "entities": r.robot.entities, "unacknowledged": r.robot.unacknowledged,
                      "silent": "silent" if r.robot.stale else
                      ("stopped" if not r.robot.online else ""),
                      "diagnosis": ", ".join(r.robot.diagnosis)} for r in view.rows]}


def fleet_router(store: FleetCache, sites: SiteMap, page: PageRenderer,
                 require: Requirer) -> APIRouter:
    router = APIRouter()

    @router.get("/")
    async def fleet(request: Request) -> Response:
        session = require(request)
        query = query_of(dict(request.query_params))
        view: FleetPage = fleet_page(store.fleet(), sites.site_of, query)
        links = {
            "older": urlencode(query.params(view.page + 1)) if view.page + 1 < view.pages
            else "",
            "newer": urlencode(query.params(view.page - 1)) if view.page > 0 else None,
            "stream": urlencode(query.params(view.page)),
            "status": {s: urlencode({**query.params(0), "status": s}) for s in WORST_FIRST},
        }
        return page(request, "fleet.html", session, view=view, links=links, nav="fleet",
                    statuses=WORST_FIRST)

    return router
