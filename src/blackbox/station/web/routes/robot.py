"""The robot page: headline, status, entity tree, health timeline, recent events, live;
the timeline as a file; enrolling a robot's key."""

from __future__ import annotations

import time
from typing import Any
from urllib.parse import quote

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import RedirectResponse, Response
from markupsafe import Markup

from blackbox.station.auth import Role
from blackbox.station.headline import Headline, diagnosis_headlines, event_headline
from blackbox.station.store import StationStore
from blackbox.station.timeline import ZOOMS
from blackbox.station.web.context import WebContext
from blackbox.station.web.formats import fmt_ago, fmt_clock, fmt_time
from blackbox.station.web.health_timeline import timeline_of
from blackbox.station.web.live import Snapshot, StreamQuery


def headlines_of(store: StationStore, r: str) -> list[Headline]:
    """The robot page's headlines: the diagnosis, with each component's latest failure."""
    summary, diagnosis = store.robot(r), store.diagnosis(r)
    failures = {name: (ev.text, ev.details, ev.time) for name in diagnosis.components
                for ev in store.events(r, entity=name, kinds=["failure"], limit=1).events}
    degraded = [e.name for e in store.entities(r)
                if e.kind != "robot" and e.status == "DEGRADED"]
    return diagnosis_headlines(summary.name, diagnosis.components, diagnosis.since,
                               failures, degraded, stale=summary.stale,
                               online=summary.online)


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    store, auth, operations = web.store, web.auth, web.operations

    def robot_state(r: str) -> dict[str, Any]:
        summary = store.robot(r)
        diagnosis = store.diagnosis(r)
        now = time.time()
        return {"status": summary.status, "stale": summary.stale,
                "last_heard": fmt_ago(summary.last_heard),
                "diagnosis": ", ".join(diagnosis.components),
                "explanation": diagnosis.explanation,
                "entities": {str(e.instance_id): e.status for e in store.entities(r)},
                "headlines": [h.to_dict(now) for h in headlines_of(store, r)],
                "events": [{"id": ev.id, "time": fmt_time(ev.time),
                            "clock": fmt_clock(ev.time), "robot": ev.robot_id,
                            "entity": ev.entity, "kind": ev.kind, "origin": ev.origin,
                            "text": ev.text, "acknowledged_by": ev.acknowledged_by,
                            "headline": event_headline(ev.kind, ev.entity, ev.text,
                                                       ev.details, ev.time).to_dict(now)}
                           for ev in store.events(r, limit=20).events]}

    def robot_snapshot(query: StreamQuery) -> Snapshot:
        return lambda: robot_state(query.r)

    web.live.add("robot", robot_snapshot)

    @routes.get("/robot/timeline.svg")
    async def timeline_svg(request: Request, r: str, zoom: str = "1h", entity: str = "",
                           links: bool = False) -> Response:
        """The timeline as a file for an incident report (no links: it stands alone), or
        with ``links`` the page's own picture, redrawn when the robot's state changes."""
        web.require(request)
        if links:
            return Response(timeline_of(store, r, zoom, entity), media_type="image/svg+xml")
        name = f"{r}-timeline-{zoom}.svg".replace("/", "_").replace("#", "")
        return Response(timeline_of(store, r, zoom, entity, links=False),
                        media_type="image/svg+xml",
                        headers={"Content-Disposition":
                                 f"attachment; filename*=UTF-8''{quote(name)}"})

    @routes.get("/robot")
    async def robot(request: Request, r: str, zoom: str = "1h") -> Response:
        session = web.require(request)
        summary = store.robot(r)
        entities = store.entities(r)
        ibits = store.ibit_runs(r, limit=1)
        keys = getattr(operations, "robot_keys", None)  # trust on first use (enrolment.py)
        seen = [k.public_key for k in keys.seen() if k.robot_id == summary.robot_id] \
            if keys is not None and keys.trusted(summary.robot_id) is None else []
        return web.page(request, "robot.html", session, robot=summary, ref=r,
                        entities=entities, diagnosis=store.diagnosis(r),
                        headlines=headlines_of(store, r), nav="fleet",
                        zoom=zoom if zoom in ZOOMS else "1h", zooms=list(ZOOMS),
                        timeline=Markup(timeline_of(store, r,
                                                    zoom if zoom in ZOOMS else "1h")),
                        events=store.events(r, limit=20).events,
                        last_ibit=ibits[0] if ibits else None, seen_keys=seen,
                        live=web.live.source("robot", r=r))

    @routes.post("/robot/enrol")
    async def robot_enrol(request: Request) -> Response:
        """Trust on first use, confirmed by an administrator: enrol the one key seen."""
        from blackbox.station.enrolment import EnrolmentError

        session, form, target = await web.change(request, "robot.enrol", Role.ADMIN)
        keys = getattr(operations, "robot_keys", None)
        robot_id = form.get("robot", "")[:200]
        try:
            if keys is None:
                raise EnrolmentError("this station keeps no robot keys")
            enrolled = keys.confirm_seen(robot_id)
        except EnrolmentError as exc:
            auth.audit(session.user.name, "robot.enrol", target, "refused",
                       web.address(request), str(exc))
            raise HTTPException(400, str(exc)) from None
        auth.audit(session.user.name, "robot.enrol", target, "ok", web.address(request),
                   f"key {enrolled.public_key}")
        return RedirectResponse(f"/robot?r={quote(robot_id, safe='')}", status_code=303)

    return routes
