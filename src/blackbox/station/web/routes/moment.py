"""One moment of a robot's history: what a click on a timeline span opens.

The operator reconstructing an incident clicks the red span and wants both halves of the
story at once: the events of that moment (what the black box concluded) and the charts of
the entity's observed values around it (what it saw). The charts reach a little before and
after the span, so the change itself is in the picture.
"""

from __future__ import annotations

import json
from urllib.parse import urlencode

from fastapi import APIRouter, Request
from fastapi.responses import Response

from blackbox.station.store import STATUSES, Characteristic
from blackbox.station.web.context import WebContext
from blackbox.station.web.formats import parse_time

MAX_CHARTS = 8
"""Charts on one moment's page: the robot lane's moment may touch many entities."""
EVENTS_SHOWN = 50


def margin(since: float, until: float) -> float:
    """How far the charts reach beyond the span: a fifth of it, 30 s at least, 1 h at most."""
    return min(3600.0, max(30.0, (until - since) / 5))


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    store = web.store

    @routes.get("/moment")
    async def moment(request: Request, r: str, since: str, until: str, entity: str = "",
                     status: str = "") -> Response:
        session = web.require(request)
        summary = store.robot(r)
        start, end = parse_time(since), parse_time(until)
        if start is None or end is None or end < start:
            raise ValueError("a moment needs since <= until")
        pad = margin(start, end)
        events = store.events(r, entity=entity or None, since=start - pad, until=end + pad,
                              limit=EVENTS_SHOWN).events
        if entity:
            node = store.entity_by_name(r, entity)
            shown = [node] if node is not None else []
        else:  # the robot lane: the entities its events of that moment name, in order
            named = list(dict.fromkeys(ev.entity for ev in reversed(events) if ev.entity))
            shown = [n for n in (store.entity_by_name(r, name) for name in named)
                     if n is not None]
        chars: list[tuple[str, Characteristic]] = []
        for node in shown:
            chars += [(node.name, c) for c in store.characteristics(r, node.instance_id)]
        chars = chars[:MAX_CHARTS]
        series = {str(c.instance_id): [[p.time for p in pts], [p.value for p in pts]]
                  for _, c in chars
                  for pts in [store.series(r, c.instance_id, since=start - pad, until=end + pad,
                                           max_points=600)]}
        return web.page(request, "moment.html", session, robot=summary, ref=r,
                        entity=entity, lane_status=status if status in STATUSES else "",
                        since=start, until=end, pad=pad,
                        events=events, characteristics=chars, nav="fleet",
                        series_json=json.dumps(series),
                        nodes={n.name: n.instance_id for n in shown},
                        all_events="/events?" + _query(r, entity, since, until))

    return routes


def _query(r: str, entity: str, since: str, until: str) -> str:
    return urlencode({"robot": r, "since": since, "until": until,
                      **({"entity": entity} if entity else {})})
