"""A source over events already in memory.

Used to replay recorded or generated event streams through the real pipeline (benchmarks,
tests, post-mission analysis of a JSON export). Time advances only through ``poll``.
"""

from __future__ import annotations

from collections.abc import Iterable

from blackbox.events import Event, Interest, TopicSchema
from blackbox.sources.base import Capabilities


class MemorySource:
    """Replays a time-ordered list of events; the clock is the last ``poll`` horizon."""

    name = "memory"
    capabilities = Capabilities(simulated_clock=True)

    def __init__(self, events: Iterable[Event], start_time: float = 0.0,
                 schemas: dict[str, TopicSchema] | None = None) -> None:
        self._events = sorted(events, key=lambda e: e.time)
        self._pos = 0
        self._now = start_time
        self._schemas = schemas or {}
        self.interest: Interest | None = None

    def start(self, interest: Interest) -> None:
        self.interest = interest

    def now(self) -> float:
        return self._now

    def poll(self, until: float) -> list[Event]:
        events = self._events
        start = end = self._pos
        n = len(events)
        while end < n and events[end].time <= until:
            end += 1
        self._pos = end
        self._now = max(self._now, until)
        return events[start:end]

    def schema(self, topic: str) -> TopicSchema | None:
        return self._schemas.get(topic)

    def close(self) -> None:
        return None
