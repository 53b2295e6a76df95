"""``/api/stream``: a page's live updates as Server-Sent Events.

The stream sends the page's snapshot (from the table in :mod:`blackbox.station.web.live`)
whenever the store commits a change and it differs from the last one sent, re-checks the
session at every wake, and beats while nothing changes so proxies keep it open.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response, StreamingResponse

from blackbox.station.web.context import SESSION_COOKIE, Id, WebContext
from blackbox.station.web.live import ChangeSignal, StreamQuery, UnknownLiveView

LOOK_INTERVAL = 0.25
"""Least seconds between two snapshots of one stream. Why: a station ingesting a fleet
commits some twenty times a second, and the fleet page's snapshot of 1,000 robots costs
tens of milliseconds; a look after the pause sees every commit made meanwhile."""


def router(web: WebContext, changes: ChangeSignal) -> APIRouter:
    routes = APIRouter()
    store, auth, settings, stop = web.store, web.auth, web.settings, web.stop

    @routes.get("/api/stream")
    async def stream(request: Request, view: str = "fleet", r: str = "",
                     id: Id = 0) -> Response:
        session = web.require(request)
        token = request.cookies.get(SESSION_COOKIE)

        def still_allowed() -> bool:
            """The session is still open with the role it had (not logged out, expired,
            removed, re-passworded or re-roled): checked at every wake of the stream."""
            now = auth.session(token, touch=False)
            return now is not None and now.user.role == session.user.role
        try:
            snapshot = web.live.snapshot(view, StreamQuery(r=r, id=id, params=tuple(
                request.query_params.items())))
        except UnknownLiveView:
            raise HTTPException(400, "unknown view") from None
        snapshot()  # an unknown robot or a bad id is an error answer, not a broken stream

        async def events() -> AsyncIterator[str]:
            wake = changes.register()
            try:
                async for chunk in stream_events(wake):
                    yield chunk
            finally:
                changes.unregister(wake)

        async def stream_events(wake: asyncio.Event) -> AsyncIterator[str]:
            seq = -1
            last_sent = ""
            last_beat = last_look = time.monotonic()
            yield "retry: 1000\n\n"
            while not stop.is_set():
                if not still_allowed() or await request.is_disconnected():
                    break
                current = store.sequence
                if current != seq or time.monotonic() - last_look > 2.0:  # staleness ages
                    pause = last_look + LOOK_INTERVAL - time.monotonic()
                    if seq != -1 and pause > 0:
                        await asyncio.sleep(pause)
                        current = store.sequence
                    seq = current
                    last_look = time.monotonic()
                    try:
                        text = json.dumps(snapshot())
                    except (LookupError, OverflowError):
                        text = "{}"
                    if text != last_sent:
                        last_sent = text
                        last_beat = time.monotonic()
                        yield f"event: state\ndata: {text}\n\n"
                        continue
                if time.monotonic() - last_beat > settings.sse_heartbeat:
                    last_beat = time.monotonic()
                    yield ": beat\n\n"
                wake.clear()
                if store.sequence == seq:
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(wake.wait(), 0.5)
            yield "event: end\ndata: {}\n\n"

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store",
                                          "X-Accel-Buffering": "no"})

    return routes
