"""The fleet page's view of 1,000 robots: counts by status, worst first, filters, pages.

A control room with a large fleet looks first for what is wrong: the page leads with how
many robots are in each status, lists the worst first (not operational, degraded, unknown,
then operational; among equals the one with most unacknowledged alarms, then the most
faulty entities, then by name) and lets the operator narrow the list by a search (robot or
site, any part of the name, any case), a site and a status, 50 rows a page. This module is
pure: it takes the store's :class:`~blackbox.station.store.RobotSummary` rows and a way to
name a robot's site, so the page, its live updates and the tests agree on one order.

A robot's site comes from the station's own configuration: the ``sites:`` of the alert
rules file (``site: [robot names or globs]``, see docs/station.md), the same sites the alert
rules match on. A robot no site names has the site ``""`` (shown as "-").
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from blackbox.station.store import STATUSES, RobotSummary

WORST_FIRST = ("NOT_OPERATIONAL", "DEGRADED", "UNKNOWN", "OPERATIONAL")
"""The order of statuses on the fleet page: what needs an operator first."""
PAGE_SIZE = 50
"""Robots per page: one screen an operator scans without losing the counts above it."""
MAX_SEARCH = 100
"""Characters of a search kept (a longer one cannot match a robot name anyway)."""


@dataclass(frozen=True, slots=True)
class FleetQuery:
    """What the operator asked for: ``search`` (part of a robot's name or site), ``site``
    (exactly), ``status`` (one of :data:`WORST_FIRST`) and ``page`` (from 0)."""

    search: str = ""
    site: str = ""
    status: str = ""
    page: int = 0

    @classmethod
    def of(cls, search: str = "", site: str = "", status: str = "",
           page: int = 0) -> FleetQuery:
        """The query from URL parameters; an unknown status is a ``ValueError`` (400)."""
        status = status.strip().upper()
        if status and status not in STATUSES:
            raise ValueError(f"unknown status {status[:30]!r}: one of {', '.join(WORST_FIRST)}")
        return cls(search.strip()[:MAX_SEARCH], site.strip()[:MAX_SEARCH], status,
                   max(0, page))

    def params(self, page: int | None = None) -> dict[str, str]:
        """The query as URL parameters (empty ones left out), at ``page`` if given."""
        at = self.page if page is None else page
        items = {"search": self.search, "site": self.site, "status": self.status,
                 "page": str(at) if at else ""}
        return {k: v for k, v in items.items() if v}


@dataclass(frozen=True, slots=True)
class FleetRow:
    """One robot on the page: its summary and its site (``""``: none)."""

    robot: RobotSummary
    site: str


@dataclass(frozen=True, slots=True)
class FleetPage:
    """One page of the fleet: ``counts`` per status over the whole fleet (the headline
    never changes with the filter), ``matched`` robots the filter kept, ``rows`` on this
    page (worst first), the page number and how many pages there are, and the sites known."""

    counts: Mapping[str, int]
    total: int
    matched: int
    rows: tuple[FleetRow, ...]
    page: int
    pages: int
    sites: tuple[str, ...]
    query: FleetQuery


class SiteMap:
    """Names each robot's site from ``sites`` (site name -> robot names or globs, the alert
    configuration's ``sites:``); the first site listing a robot wins."""

    def __init__(self, sites: Mapping[str, Sequence[str]] | None = None) -> None:
        self.sites = {name: tuple(globs) for name, globs in (sites or {}).items()}

    def site_of(self, robot: str) -> str:
        for name, globs in self.sites.items():
            if any(fnmatch.fnmatchcase(robot, g) for g in globs):
                return name
        return ""


def worst_first(row: FleetRow) -> tuple[int, int, int, str]:
    """Sort key: status by :data:`WORST_FIRST`, then most unacknowledged alarms, most
    faulty entities, then the name."""
    r = row.robot
    rank = WORST_FIRST.index(r.status) if r.status in WORST_FIRST else len(WORST_FIRST)
    return rank, -r.unacknowledged, -r.failing, r.name


def _matches(row: FleetRow, query: FleetQuery) -> bool:
    if query.status and row.robot.status != query.status:
        return False
    if query.site and row.site != query.site:
        return False
    if query.search:
        needle = query.search.casefold()
        return needle in row.robot.name.casefold() or needle in row.site.casefold()
    return True


def fleet_page(robots: Sequence[RobotSummary], site_of: Callable[[str], str],
               query: FleetQuery, page_size: int = PAGE_SIZE) -> FleetPage:
    """The page ``query`` asks for; a page beyond the last shows the last."""
    rows = [FleetRow(r, site_of(r.name)) for r in robots]
    counts = dict.fromkeys(WORST_FIRST, 0)
    for row in rows:
        counts[row.robot.status] = counts.get(row.robot.status, 0) + 1
    kept = sorted((row for row in rows if _matches(row, query)), key=worst_first)
    pages = max(1, math.ceil(len(kept) / page_size))
    page = min(query.page, pages - 1)
    shown = tuple(kept[page * page_size:(page + 1) * page_size])
    sites = tuple(sorted({row.site for row in rows if row.site}))
    return FleetPage(counts, len(rows), len(kept), shown, page, pages, sites, query)
