"""Problems the station could not fix itself, kept for the operator's page and the log.

A full disk, a database that went away, a listener that raised: each is counted under its
(source, message) with when it was first and last seen, so a problem that repeats every
second is one line with a count, not a flood. At most 200 distinct problems are kept.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from blackbox.station.records import Problem, clip

MAX_PROBLEMS = 200

log = logging.getLogger("blackbox.station.store")


@dataclass(slots=True)
class _ProblemState:
    source: str
    message: str
    first: float
    last: float
    count: int = 1


class ProblemLog:
    """Distinct problems with counts (thread-safe); ``on_new`` is called for each new one
    (the store announces it on the change feed) and each new one is logged as a warning."""

    def __init__(self, clock: Callable[[], float] = time.time,
                 on_new: Callable[[], None] | None = None) -> None:
        self.clock = clock
        self.on_new = on_new
        self._problems: dict[tuple[str, str], _ProblemState] = {}
        self._lock = threading.Lock()

    def report(self, source: str, message: str) -> None:
        now = self.clock()
        key = (clip(source, 100), clip(message, 500))
        with self._lock:
            p = self._problems.get(key)
            if p is None:
                if len(self._problems) >= MAX_PROBLEMS:
                    oldest = min(self._problems, key=lambda k: self._problems[k].last)
                    del self._problems[oldest]
                self._problems[key] = _ProblemState(key[0], key[1], now, now)
                new = True
            else:
                p.last = now
                p.count += 1
                new = False
        if new:
            log.warning("station %s: %s", key[0], key[1])
            if self.on_new is not None:
                self.on_new()

    def recent(self, limit: int = 50) -> list[Problem]:
        """The most recent problems, newest first."""
        with self._lock:
            items = sorted(self._problems.values(), key=lambda p: p.last, reverse=True)
        return [Problem(p.source, p.message, p.first, p.last, p.count)
                for p in items[: max(0, limit)]]

    def clear(self, source: str) -> None:
        with self._lock:
            for key in [k for k in self._problems if k[0] == source]:
                del self._problems[key]
