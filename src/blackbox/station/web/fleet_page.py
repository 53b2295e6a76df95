"""The fleet page's rows and live state: counts, worst first, filters, pages (its route is
:mod:`blackbox.station.web.routes.fleet`).

One module so that the page's route and the state its live stream sends are built from
one :class:`~blackbox.station.fleet_view.FleetPage`: the rows the browser redraws are the
rows the server would render for the same query.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from blackbox.station.fleet_view import FleetQuery, SiteMap, fleet_page
from blackbox.station.store import RobotSummary, StationStore
from blackbox.station.web.formats import robot_ref


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
            sequence, now = self.store.sequence, self.store.clock()  # staleness ages by it
            if sequence != self._key[0] or not 0 <= now - self._key[1] <= self.max_age:
                self._fleet = self.store.fleet()
                self._key = (sequence, now)
            return self._fleet


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
