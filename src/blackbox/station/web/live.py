"""The one table of live pages: each page's snapshot, registered beside its route.

A page that updates itself names its snapshot here (``live.add("robot", ...)`` in the
page's router module) and renders ``live.source("robot", r=...)`` into its root element's
``data-live`` attribute: that is the stream's URL, so the browser never needs a table of
page names of its own. ``static/station.js`` applies a snapshot by its fields (elements
marked ``data-bind``/``data-paint`` take scalar fields; the few structured fields such as
``events`` or ``entities`` have one drawing function each), whatever page it came from.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlencode

from blackbox.errors import BlackBoxError
from blackbox.station.store import StationStore

Snapshot = Callable[[], dict[str, Any]]


@dataclass(frozen=True, slots=True)
class StreamQuery:
    """What a live stream's URL says: the robot (``r``) and a number (entity, run, log)."""

    r: str = ""
    id: int = 0
    params: tuple[tuple[str, str], ...] = ()
    """Every parameter of the stream's URL (a page's filters, e.g. the fleet's search)."""


class UnknownLiveView(BlackBoxError, LookupError):
    """A page or a stream named a live view no router registered."""


class LiveViews:
    """Live view name -> how to take its snapshot for one stream's query."""

    def __init__(self) -> None:
        self._views: dict[str, Callable[[StreamQuery], Snapshot]] = {}

    def add(self, name: str, snapshot: Callable[[StreamQuery], Snapshot]) -> None:
        if name in self._views:
            raise ValueError(f"live view {name!r} is registered twice")
        self._views[name] = snapshot

    def names(self) -> list[str]:
        return sorted(self._views)

    def snapshot(self, name: str, query: StreamQuery) -> Snapshot:
        if name not in self._views:
            raise UnknownLiveView(f"unknown live view {name[:40]!r}")
        return self._views[name](query)

    def source(self, name: str, r: str = "", id: int | None = None,
               params: Mapping[str, str] | None = None) -> str:
        """The stream URL a page of view ``name`` listens to (its ``data-live`` attribute);
        ``params`` are the page's own filters, which its snapshot reads back."""
        if name not in self._views:
            raise UnknownLiveView(f"unknown live view {name!r}")
        query = {**(params or {}), "view": name, **({"r": r} if r else {}),
                 **({"id": str(id)} if id is not None else {})}
        return "/api/stream?" + urlencode(query)


class ChangeSignal:
    """Wakes every open live stream when the store commits a change.

    The store calls back on its writing thread; the callback only schedules setting one
    :class:`asyncio.Event` per stream on the event loop, so streams wait without holding a
    worker thread each (a control room may keep many pages open).
    """

    def __init__(self, store: StationStore) -> None:
        self._store = store
        self._events: set[asyncio.Event] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._remove: Callable[[], None] | None = None

    def register(self) -> asyncio.Event:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
            self._remove = self._store.add_listener(self._changed)
        event = asyncio.Event()
        self._events.add(event)
        return event

    def unregister(self, event: asyncio.Event) -> None:
        self._events.discard(event)

    def _changed(self, change: object) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        for event in list(self._events):
            event.set()

    def close(self) -> None:
        if self._remove is not None:
            self._remove()
