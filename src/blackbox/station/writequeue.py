"""The station's write queue: changes are queued by the follower and committed in batches.

The follower must never wait on the database (a robot's samples keep coming), and a write
that fails must lose nothing: each change is a small function of a connection, queued in
memory; :meth:`WriteQueue.flush` takes everything queued (a short hold of :attr:`lock`) and
applies it in one transaction while the follower queues the next batch: only
:attr:`flushing` is held while the database works, so a slow server (a PostgreSQL round
trip per statement) never stops ingest. When the transaction fails (disk full, the
PostgreSQL server gone, a deadlock with another station process) it is rolled back, the
batch goes back to the front of the queue and is retried, and the failure is a problem on
the operator's page. Nothing already committed is touched. A connection to a server that
went away is replaced at the next try.

The queue is bounded (``max_pending``). Over the bound the station degrades in steps, each
counted and reported, never silently: chart points of one characteristic are coalesced
(the newest wins), then the oldest chart points are dropped, and only then the oldest of
anything else. Events, statuses and current values are chart points of nothing: they go
last.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from blackbox.station.database import (
    Connection,
    Database,
    DatabaseError,
    append_rows,
    write_batch,
)
from blackbox.station.problems import ProblemLog

Op = Callable[[Connection], None]
"""One queued change: applied to the write connection inside the flush's transaction."""

T = TypeVar("T")

RETRY_AFTER = 1.0
"""Seconds a failed flush waits before the next (unless forced)."""


@dataclass(slots=True)
class PendingWrite:
    """A queued change: a function of the connection (``op``), or one row of a statement
    (``sql`` and ``args``, ``op`` ``None``) that the flush sends with many others at once."""

    op: Op | None
    robot: int | None
    topic: str
    droppable: bool = False
    sql: str = ""
    args: tuple[Any, ...] = ()
    append_to: str = ""
    """A row of every column of this table (``args``), appended whatever else the batch
    does, so it may be written before the rest (:func:`~blackbox.station.database.
    append_rows`: PostgreSQL's COPY); ``sql`` is then unused."""
    series: tuple[int, int] | None = None
    """For a chart point: its characteristic (robot, instance), whose points may be
    coalesced when the queue is full (:meth:`WriteQueue._shed`)."""
    more_robots: set[int] | None = None
    """Further robots a batched change (:meth:`WriteQueue.joins_batch`) touches."""
    gone: bool = False
    """Dropped from the queue unwritten (:meth:`WriteQueue._shed`): not to be updated."""


@dataclass(frozen=True, slots=True)
class Committed:
    """What one successful flush wrote: robots touched and change-feed topics."""

    robots: frozenset[int]
    topics: frozenset[str]


@dataclass(slots=True)
class FlushTimes:
    """How long changes waited to be committed, as of the last flush that wrote any: the
    station's own share of a fault -> colour change (``/metrics``)."""

    lag: float = 0.0
    """Seconds from the oldest change of the last committed batch being queued to its
    commit."""
    lag_max: float = 0.0
    """The largest :attr:`lag` since the station started."""
    seconds: float = 0.0
    """Seconds the last committed flush spent writing (its transaction)."""
    rows: int = 0
    """Changes the last committed flush wrote."""


class WriteQueue:
    """Queued changes and the one write connection of a store (thread-safe).

    Two locks, always taken in this order: :attr:`flushing` (one flush or direct write at
    a time, held while the database works) and :attr:`lock` (the queue itself, held for
    moments). Whoever queues takes only :attr:`lock`."""

    def __init__(self, database: Database, problems: ProblemLog, *, max_pending: int,
                 clock: Callable[[], float] = time.time) -> None:
        self.database = database
        self.problems = problems
        self.max_pending = max_pending
        self.clock = clock
        self.lock = threading.RLock()
        self.flushing = threading.RLock()
        self._pending: deque[PendingWrite] = deque()
        self._dropped_points = 0
        self._coalesced_points = 0
        self._dropped_changes = 0
        self._last_failed = -math.inf
        self._last_change: PendingWrite | None = None
        self._oldest = 0.0
        """When the oldest change still queued was queued (``monotonic``)."""
        self.times = FlushTimes()
        self._db: Connection | None = database.connect()
        self.closed = False

    @property
    def pending(self) -> int:
        return len(self._pending)

    @property
    def dropped_points(self) -> int:
        """Chart points dropped because the queue was full (the oldest first)."""
        return self._dropped_points

    @property
    def coalesced_points(self) -> int:
        """Chart points replaced by a newer point of the same characteristic because the
        queue was full (the chart lost resolution, the current value is kept)."""
        return self._coalesced_points

    @property
    def dropped_changes(self) -> int:
        """Changes other than chart points dropped because the queue stayed full."""
        return self._dropped_changes

    @property
    def failing(self) -> bool:
        """The last flush failed and nothing has been committed since."""
        return self._last_failed > -math.inf

    def connection(self) -> Connection:
        """The write connection (call with :attr:`flushing` held), reconnected if it was
        lost."""
        if self._db is None:
            self._db = self.database.connect()
        return self._db

    def _drop_connection(self) -> None:
        """Forget a connection a server may have closed (never an in-memory SQLite one:
        that would lose the database)."""
        if self._db is None or self.database.memory or self.database.dialect == "sqlite":
            return
        with contextlib.suppress(Exception):
            self._db.close()
        self._db = None

    def add(self, op: Op, robot: int | None, topic: str, droppable: bool = False) -> None:
        with self.lock:
            if not self._pending:
                self._oldest = time.monotonic()
            self._last_change = PendingWrite(op, robot, topic, droppable)
            self._pending.append(self._last_change)
            if len(self._pending) > self.max_pending:
                self._shed()

    def joins_batch(self, op: Op, robot: int) -> bool:
        """Whether ``op`` is still the last change queued (rows may have been queued after
        it) and not yet committed; then the caller may add to what it writes, and
        ``robot`` is counted among the robots it touched. Why: a change per entity status
        was a round trip (and a read) per sample; one change for a run of them is one
        ``executemany``. Call with :attr:`lock` held."""
        last = self._last_change
        if last is None or last.op is not op:
            return False
        if robot != last.robot:
            if last.more_robots is None:
                last.more_robots = set()
            last.more_robots.add(robot)
        return True

    def add_row(self, sql: str, args: tuple[Any, ...], robot: int | None, topic: str,
                droppable: bool = False, series: tuple[int, int] | None = None,
                append_to: str = "") -> PendingWrite:
        """One row of ``sql``, sent in one ``executemany`` with every other row of the same
        statement queued since the last :meth:`add`ed change. Why: one statement per
        characteristic value was one round trip per value to a PostgreSQL server (about 580
        values a second at most on this machine, where 1,000 robots send 11,000); many rows
        of a statement go in one pipeline. Rows of different statements between two
        changes may be applied in any order, so only statements whose order among each
        other does not matter are queued as rows (appends, upserts of other tables or of
        other columns); rows of one statement keep their order, and a change queued with
        :meth:`add` applies after every row queued before it."""
        with self.lock:
            if not self._pending:
                self._oldest = time.monotonic()
            row = PendingWrite(None, robot, topic, droppable, sql, args, append_to, series)
            self._pending.append(row)
            if len(self._pending) > self.max_pending:
                self._shed()
            return row

    def _shed(self) -> None:
        """Over the bound: coalesce queued chart points per characteristic (the newest
        wins), then drop the oldest chart points down to half the bound, then the oldest
        of anything else; every step counted and reported as a problem."""
        coalesced = dropped = refused = 0
        newest: set[tuple[int, int]] = set()
        for item in reversed(self._pending):
            if item.series is None:
                continue
            if item.series in newest:
                item.gone = True
                coalesced += 1
            else:
                newest.add(item.series)
        kept: deque[PendingWrite] = deque(i for i in self._pending if not i.gone)
        excess = len(kept) - self.max_pending // 2
        if len(kept) > self.max_pending and excess > 0:
            rest: deque[PendingWrite] = deque()
            for item in kept:
                if excess > 0 and item.droppable:
                    excess -= 1
                    dropped += 1
                    item.gone = True
                    continue
                rest.append(item)
            kept = rest
        while len(kept) > self.max_pending:
            gone = kept.popleft()
            gone.gone = True
            refused += 1
            if gone is self._last_change:
                self._last_change = None
        self._pending = kept
        self._coalesced_points += coalesced
        self._dropped_points += dropped
        self._dropped_changes += refused
        if refused:
            self.problems.report("store", f"write queue full ({self.max_pending} changes): "
                                          f"{self._dropped_changes} oldest queued changes "
                                          "dropped so far")
        self.problems.report("store-queue", f"write queue full ({self.max_pending} "
                                            "changes), the database cannot keep up: "
                                            f"{self._coalesced_points} chart points "
                                            "coalesced (the newest value of each "
                                            f"characteristic kept), {self._dropped_points} "
                                            "dropped so far; events and statuses are kept")

    def flush(self, force: bool = False,
              taken: Callable[[], None] | None = None) -> Committed | None:
        """Commit everything queued in one transaction. ``None`` when something stays queued
        (the database failed, or a failed flush is less than a second ago and not
        ``force``); otherwise what was committed (empty when nothing was queued).
        ``taken`` is called (with :attr:`lock` held) once the batch left the queue: from
        then on the caller's changes are queued for the next flush."""
        with self.flushing:
            with self.lock:
                if self.closed:
                    return None
                now = self.clock()
                if not self._pending:
                    return Committed(frozenset(), frozenset())
                if not force and now - self._last_failed < RETRY_AFTER:
                    return None
                batch = list(self._pending)
                oldest = self._oldest
                self._pending.clear()
                self._last_change = None  # taken: nothing may be added to it any more
                if taken is not None:
                    taken()
            started = time.monotonic()
            try:
                db = self.connection()
                try:
                    db.begin()
                    appended = _append(db, batch)  # by COPY, before the rest
                    with write_batch(db):  # the rest and COMMIT in one pipeline
                        _apply(db, batch if not appended else
                               [i for i in batch if not i.append_to])
                        db.commit()
                except BaseException:
                    with contextlib.suppress(DatabaseError):
                        db.rollback()
                    raise
            except BaseException as exc:
                with self.lock:  # back to the front of the queue, before anything newer
                    self._pending.extendleft(reversed(batch))
                    self._oldest = oldest
                    if len(self._pending) > self.max_pending:
                        self._shed()
                if not isinstance(exc, DatabaseError):
                    raise
                self._drop_connection()
                self._last_failed = now
                self.problems.report("store", f"cannot write {self.database.describe()}: "
                                              f"{exc} ({len(batch)} changes kept in memory, "
                                              "retried)")
                return None
            done = time.monotonic()
            self.times.seconds, self.times.rows = done - started, len(batch)
            self.times.lag = done - oldest
            self.times.lag_max = max(self.times.lag_max, self.times.lag)
            if self._last_failed > -math.inf:
                self._last_failed = -math.inf
                self.problems.clear("store")
                self.problems.report("store-recovered",
                                     f"{self.database.describe()} writable again")
        robots = {i.robot for i in batch if i.robot is not None}
        for item in batch:
            if item.more_robots:
                robots |= item.more_robots
        return Committed(frozenset(robots), frozenset(i.topic for i in batch if i.topic))

    def run_now(self, what: Callable[[Connection], T]) -> T:
        """Run ``what`` on the write connection now (call after a successful flush, with
        :attr:`flushing` held, so it lands after everything queued). Raises
        :class:`DatabaseError` after dropping a lost connection."""
        try:
            return what(self.connection())
        except DatabaseError:
            self._drop_connection()
            raise

    def close(self) -> None:
        with self.flushing, self.lock:
            self.closed = True
            if self._db is not None:
                with contextlib.suppress(Exception):
                    self._db.close()
                self._db = None


def _append(db: Connection, batch: list[PendingWrite]) -> bool:
    """Write the rows of ``batch`` that are appends (:attr:`PendingWrite.append_to`), a
    table at a time; whether there were any."""
    tables: dict[str, list[tuple[Any, ...]]] = {}
    for item in batch:
        if item.append_to:
            tables.setdefault(item.append_to, []).append(item.args)
    for table, rows in tables.items():
        append_rows(db, table, rows)
    return bool(tables)


def _apply(db: Connection, batch: list[PendingWrite]) -> None:
    """Every change of ``batch`` in order; runs of rows as one ``executemany`` per statement
    (see :meth:`WriteQueue.add_row`)."""
    rows: dict[str, list[tuple[Any, ...]]] = {}
    for item in batch:
        if item.op is None:
            rows.setdefault(item.sql, []).append(item.args)
            continue
        for sql, group in rows.items():
            db.executemany(sql, group)
        rows.clear()
        item.op(db)
    for sql, group in rows.items():
        db.executemany(sql, group)
