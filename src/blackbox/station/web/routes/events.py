"""The events page (filtered, paged by cursor) and acknowledging an event."""

from __future__ import annotations

from urllib.parse import urlencode

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import RedirectResponse, Response

from blackbox.station.auth import Role
from blackbox.station.store import EVENT_KINDS
from blackbox.station.web.context import MAX_ID, WebContext, safe_next
from blackbox.station.web.formats import parse_time

EVENT_PAGE = 50
"""Events per page of /events: a page an operator scans without scrolling for long."""


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    store, auth = web.store, web.auth

    @routes.get("/events")
    async def events(request: Request, robot: str = "", entity: str = "", kind: str = "",
                     since: str = "", until: str = "", cursor: str = "") -> Response:
        session = web.require(request)
        found = store.events(robot or None, entity=entity or None,
                             kinds=[kind] if kind else None, since=parse_time(since),
                             until=parse_time(until), cursor=cursor or None, limit=EVENT_PAGE)
        filters = {"robot": robot, "entity": entity, "kind": kind, "since": since,
                   "until": until}
        more = urlencode({**filters, "cursor": found.next_cursor}) if found.next_cursor \
            else ""
        return web.page(request, "events.html", session, events=found.events,
                        kinds=EVENT_KINDS, robots=web.robots(), nav="events",
                        filters=filters, more=more, newest=urlencode(filters) if cursor else "")

    @routes.post("/ack")
    async def acknowledge(request: Request) -> Response:
        session, form, target = await web.change(request, "alarm.ack", Role.OPERATOR)
        try:
            event_id = int(form.get("event", ""))
            if not 0 <= event_id <= MAX_ID:
                raise LookupError(f"no event {event_id}")
            store.acknowledge(event_id, session.user.name, form.get("note", "")[:500])
        except (ValueError, LookupError) as exc:
            auth.audit(session.user.name, "alarm.ack", target, "refused",
                       web.address(request), str(exc))
            raise HTTPException(404, "no such event to acknowledge") from None
        auth.audit(session.user.name, "alarm.ack", target, "ok", web.address(request))
        return RedirectResponse(safe_next(form.get("back")), status_code=303)

    return routes
