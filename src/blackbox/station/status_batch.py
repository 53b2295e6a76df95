"""Entity status writes in batches, with the status history read only when it may change.

Every entity sample of every robot carries its status; at 1,000 robots that is thousands a
second, and each was a change of its own: an upsert and a read of the entity's last kept
status (:mod:`blackbox.station.status_history`), one round trip each to a PostgreSQL
server (docs/benchmarks.md). Almost always the status is the one already kept. So the
store queues a run of status writes as one change (:class:`EntityStatusBatch`), which
sends the upserts of unchanged statuses with one ``executemany`` and, for a status that
differs from the last one this process knows to be kept (:class:`KeptStatuses`), does
exactly what a single write did: the upsert, then :func:`status_history.note` (read, keep,
the robot's derived status) in order.

What this process knows is re-read from the database every :data:`RECHECK_SECONDS`, so
that another station process writing the same database (several stations on one
PostgreSQL) is heard from; and it is believed only once its transaction committed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from blackbox.station import status_history
from blackbox.station.database import Connection

RECHECK_SECONDS = 300.0
"""How long a kept status known to this process is believed without reading it again.
Another station on the same database sees the same samples and so keeps the same changes;
only one that missed samples keeps other ones, which this bounds. (10 s was one read per
entity every 10 s: 1,500 reads a second at 1,000 robots, more than a PostgreSQL server
shared with a loaded machine answered.)"""

_Key = tuple[int, int]


@dataclass
class KeptStatuses:
    """Per entity, the last status the status history keeps as this process last saw it,
    and when (``monotonic``); what a transaction learnt is :meth:`stage`\\ d and becomes
    known with :meth:`commit` (or is forgotten with :meth:`discard` if it rolled back)."""

    recheck: float = RECHECK_SECONDS
    clock: Callable[[], float] = time.monotonic
    _known: dict[_Key, tuple[str, float]] = field(default_factory=dict)
    _staged: dict[_Key, tuple[str, float]] = field(default_factory=dict)

    def kept(self, key: _Key, status: str) -> bool:
        """Whether ``status`` is the entity's last kept one, as known recently enough."""
        seen = self._staged.get(key) or self._known.get(key)
        return seen is not None and seen[0] == status and \
            self.clock() - seen[1] < self.recheck

    def load(self, statuses: dict[_Key, str]) -> None:
        """What the status history keeps, read at once (as many reads would have)."""
        now = self.clock()
        self._known.update((key, (status, now)) for key, status in statuses.items())

    def stage(self, key: _Key, status: str) -> None:
        self._staged[key] = (status, self.clock())

    def commit(self) -> None:
        self._known.update(self._staged)
        self._staged.clear()

    def discard(self) -> None:
        self._staged.clear()


@dataclass(slots=True)
class _StatusWrite:
    sql: str
    args: tuple[Any, ...]
    resource_id: int
    instance_id: int
    status: str
    updated: float | None


@dataclass
class EntityStatusBatch:
    """Entity status writes queued as one change of the store's write queue."""

    kept: KeptStatuses
    clock: Callable[[], float]
    writes: list[_StatusWrite] = field(default_factory=list)

    def add(self, sql: str, args: tuple[Any, ...], resource_id: int, instance_id: int,
            status: str, updated: float | None) -> None:
        """One entity's upsert ``sql`` with ``args``, setting ``status`` (kept in the history
        at ``updated``, or at the time of the write when ``None``)."""
        self.writes.append(_StatusWrite(sql, args, resource_id, instance_id, status, updated))

    def apply(self, db: Connection) -> None:
        """Every write in order: runs of unchanged statuses (one statement) in one
        ``executemany``, a changed status as a single write did it."""
        run: list[tuple[Any, ...]] = []
        run_sql = ""
        for w in self.writes:
            key = (w.resource_id, w.instance_id)
            if self.kept.kept(key, w.status):
                if w.sql != run_sql and run:
                    db.executemany(run_sql, run)
                    run = []
                run_sql = w.sql
                run.append(w.args)
                continue
            if run:
                db.executemany(run_sql, run)
                run = []
            db.execute(w.sql, w.args)
            status_history.note(db, w.resource_id, w.instance_id, w.status,
                                self.clock() if w.updated is None else w.updated)
            self.kept.stage(key, w.status)
        if run:
            db.executemany(run_sql, run)
