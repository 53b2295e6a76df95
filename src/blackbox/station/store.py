"""The station's database: what it heard from every robot, behind the store protocols.

The station is the place where a control room looks at a fleet, so what it shows must
survive its own restarts: robots, their entity tree and statuses, characteristics with a
short time series, the event timeline, acknowledgements, log requests with their rows and
built-in test results. :class:`StationStore` keeps them in the database it is given: an
SQLite file (``station.db``, WAL; the embedded default) or PostgreSQL (``postgresql://...``,
shared by several station processes). It implements the protocols of
:mod:`blackbox.station.protocols`; the pieces it is made of live in modules of their own:
rows (:mod:`~blackbox.station.records`), schema and migrations
(:mod:`~blackbox.station.schema`), the write queue (:mod:`~blackbox.station.writequeue`),
the change feed (:mod:`~blackbox.station.changes`), problems
(:mod:`~blackbox.station.problems`), wording (:mod:`~blackbox.station.wording`) and log
export (:mod:`~blackbox.station.logexport`).

Writing and reading are split for the two kinds of callers:

* the follower (``blackbox.station.follow``) *queues* changes with the ``put_*``/``add_*``
  methods from its one thread and calls :meth:`StationStore.flush` once per poll; a flush
  applies everything queued in one transaction; a failed one keeps the queue and retries.
* the web application *reads* with the typed methods (:meth:`fleet`, :meth:`entities`,
  :meth:`diagnosis`, :meth:`characteristics`, :meth:`series`, :meth:`events`, ...) from any
  thread; every thread has its own read connection so reads never wait for a write.

Robots are addressed by a :data:`RobotRef`: the robot id as configured on the black box
(``"thesis-robot"``), or the UCMS resource id (an ``int``, or ``"#123"``). Every other
object is addressed by its UCMS instance id within that robot.
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from functools import lru_cache
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from blackbox.record.store import LogEntry
from blackbox.station import schema, status_history
from blackbox.station.changes import Change, ChangeFeed, Subscription
from blackbox.station.database import (
    Connection,
    Database,
    DatabaseError,
    ReconnectingConnection,
    open_database,
)
from blackbox.station.logexport import export_log, iter_log_entries
from blackbox.station.problems import ProblemLog
from blackbox.station.records import (
    DEFAULT_SERIES_RETENTION,
    DEFAULT_STALE_AFTER,
    EVENT_KINDS,
    MAX_NAME,
    MAX_PAGE,
    MAX_PENDING,
    MAX_SERIES_POINTS,
    MAX_TEXT,
    ORIGINS,
    STATUSES,
    Characteristic,
    Diagnosis,
    EntityNode,
    Event,
    EventPage,
    IbitRun,
    LogRequest,
    Point,
    Problem,
    RobotRef,
    RobotSummary,
    StationStoreError,
    Threshold,
    UnknownRobot,
    clip,
    finite,
    loads,
    robot_resource,
)
from blackbox.station.schema import APPLICATION, SCHEMA_VERSION
from blackbox.station.status import robot_status
from blackbox.station.status_batch import EntityStatusBatch, KeptStatuses
from blackbox.station.status_history import StatusTrack
from blackbox.station.wording import explain
from blackbox.station.writequeue import FlushTimes, Op, PendingWrite, WriteQueue

__all__ = [
    "APPLICATION", "DEFAULT_SERIES_RETENTION", "DEFAULT_STALE_AFTER", "EVENT_KINDS",
    "MAX_NAME", "MAX_PAGE", "MAX_PENDING", "MAX_SERIES_POINTS", "MAX_TEXT", "ORIGINS",
    "SCHEMA_VERSION", "STATUSES", "Change", "Characteristic", "Diagnosis", "EntityNode",
    "Event", "EventPage", "IbitRun", "LogRequest", "Point", "Problem", "RobotRef",
    "RobotSummary", "StationStore", "StationStoreError", "Subscription", "Threshold",
    "UnknownRobot", "explain", "robot_resource",
]

MIGRATION_LOCK = 7_372_001
"""PostgreSQL advisory lock key held while a station creates or migrates the schema, so two
station processes starting together on an empty database do not both create it."""

WRITER_IDLE = 0.25
"""Seconds the writer thread waits for a wake-up before it flushes anyway (what the web
application or an operation queued), and after a failed flush."""

WRITER_SWITCH_INTERVAL = 0.001
"""Seconds a thread of a station's process should keep the interpreter's lock at most
before another may have it; the station command sets it (:func:`sys.setswitchinterval`),
a library object does not change its process. The writer waits on the database many times a
flush and, each time it returns, on the interpreter's lock, which a busy follower or web
thread keeps for up to the switch interval (5 ms by default): a flush of 36,000 rows beside
a busy thread took 1.8-2.0 s at 5 ms and 1.1-1.4 s at 1 ms (1.0-1.1 s alone)."""

_HEARD = ("INSERT INTO robots (resource_id, first_heard, last_heard) VALUES (?, ?, ?) "
          "ON CONFLICT (resource_id) DO UPDATE SET "
          "last_heard = greatest(robots.last_heard, excluded.last_heard)")


@lru_cache(maxsize=64)
def _characteristic_upsert(columns: tuple[str, ...], only_newer: bool) -> str:
    """The upsert of a characteristic's ``columns`` (built once per set of columns: a fleet
    sends ten thousand values a second, all with the same few)."""
    names = "".join(f", {k}" for k in columns)
    marks = "".join(", ?" for _ in columns)
    update = ", ".join(f"{k} = excluded.{k}" for k in columns) or "name = name"
    where = " WHERE characteristics.time IS NULL OR characteristics.time <= excluded.time" \
        if only_newer else ""
    return (f"INSERT INTO characteristics (resource_id, instance_id{names}) "
            f"VALUES (?, ?{marks}) ON CONFLICT (resource_id, instance_id) DO "
            f"UPDATE SET {update}{where}")


class StationStore:
    """The station database at ``location``: a file path, ``sqlite:///path``, ``":memory:"``
    (a throw-away one, as ``blackbox listen`` uses), ``postgresql://...``, or a
    :class:`~blackbox.station.database.Database`.

    ``stale_after``: seconds of silence after which a robot is shown ``UNKNOWN``.
    ``series_retention``: seconds of characteristic values kept for charts.
    ``clock``: wall-clock seconds (tests pass their own).
    Open it with :meth:`open` (creates or migrates the schema; a database that is not a
    station database is refused with :class:`StationStoreError`), close it with
    :meth:`close`.
    """

    def __init__(self, location: str | Path | Database, *,
                 stale_after: float = DEFAULT_STALE_AFTER,
                 series_retention: float = DEFAULT_SERIES_RETENTION,
                 max_pending: int = MAX_PENDING,
                 clock: Callable[[], float] = time.time) -> None:
        if stale_after <= 0 or series_retention <= 0:
            raise ValueError("stale_after and series_retention must be positive")
        self.database = open_database(location)
        self.path = self.database.describe()
        self.memory = self.database.memory
        self.stale_after = stale_after
        self.series_retention = series_retention
        self.clock = clock
        self._local = threading.local()
        self._readers: list[Connection] = []
        self._readers_lock = threading.Lock()
        self._problems = ProblemLog(clock, on_new=lambda: self._feed.notify(
            frozenset(), frozenset({"problems"})))
        self._feed = ChangeFeed(clock, on_listener_error=lambda exc: self.report_problem(
            "notify", f"change listener failed: {exc}"))
        self._last_prune = 0.0
        self._closed = False
        self._kept_statuses = KeptStatuses()
        self._latest: dict[tuple[Any, ...], PendingWrite] = {}
        """Queued rows that later writes of the same thing update instead of adding a row:
        a robot's last-heard time, a characteristic's current value (see _coalesce)."""
        self._status_batch: EntityStatusBatch | None = None
        self._writer: threading.Thread | None = None
        self._writer_stop = threading.Event()
        self._flush_wanted = threading.Event()
        if self.database.dialect == "sqlite" and not self.memory:
            parent = Path(self.database.url).parent
            if not parent.is_dir():
                raise StationStoreError(f"{self.path}: directory {parent} does not exist")
        try:
            self._writes = WriteQueue(self.database, self._problems, max_pending=max_pending,
                                      clock=clock)
        except DatabaseError as exc:
            raise StationStoreError(f"{self.path}: cannot open the station database: "
                                    f"{exc}") from None
        try:
            with self._writes.flushing:
                self._migrate(self._writes.connection())
                self._kept_statuses.load(
                    status_history.last_statuses(self._writes.connection()))
        except (StationStoreError, DatabaseError) as exc:
            self._writes.close()
            if isinstance(exc, StationStoreError):
                raise
            raise StationStoreError(f"{self.path}: cannot use the station database: "
                                    f"{exc}") from None

    @classmethod
    def open(cls, location: str | Path | Database = "station.db",
             **kwargs: Any) -> StationStore:
        return cls(location, **kwargs)

    @property
    def max_pending(self) -> int:
        return self._writes.max_pending

    @max_pending.setter
    def max_pending(self, value: int) -> None:
        self._writes.max_pending = value

    # ---- connections ------------------------------------------------------------------------

    def _use_wal(self, db: Connection) -> None:
        if self.memory or self.database.dialect != "sqlite":
            return
        mode = db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            raise StationStoreError(f"{self.path}: cannot use WAL mode ({mode})")
        db.execute("PRAGMA synchronous=NORMAL")

    def _reader(self) -> Connection:
        db: Connection | None = getattr(self._local, "db", None)
        if db is None:
            try:
                db = ReconnectingConnection(self.database, read_only=True)
            except DatabaseError as exc:
                raise StationStoreError(f"{self.path}: cannot read: {exc}") from None
            self._local.db = db
            with self._readers_lock:
                self._readers.append(db)
        return db

    def _forget_reader(self, db: Connection) -> None:
        """Drop a read connection the server may have closed; the next read reconnects."""
        self._local.db = None
        with self._readers_lock, contextlib.suppress(ValueError):
            self._readers.remove(db)
        with contextlib.suppress(Exception):
            db.close()

    @contextlib.contextmanager
    def _read(self) -> Iterator[Connection]:
        if self.memory:  # the write connection is the only one
            with self._writes.flushing:
                try:
                    yield self._writes.connection()
                except DatabaseError as exc:
                    raise StationStoreError(f"{self.path}: cannot read: {exc}") from None
            return
        db = self._reader()
        try:
            yield db
        except DatabaseError as exc:
            if self.database.dialect != "sqlite":
                self._forget_reader(db)
            self.report_problem("store-read", f"cannot read {self.path}: {exc}")
            raise StationStoreError(f"{self.path}: cannot read: {exc}") from None

    def _migrate(self, db: Connection) -> None:
        postgres = self.database.dialect == "postgresql"
        if postgres:
            db.begin()
            db.execute("SELECT pg_advisory_xact_lock(?)", (MIGRATION_LOCK,))
        try:
            self._migrate_locked(db)
        except BaseException:
            if postgres:
                with contextlib.suppress(DatabaseError):
                    db.rollback()
            raise
        if postgres:
            db.commit()

    def _migrate_locked(self, db: Connection) -> None:
        dialect = self.database.dialect
        try:
            tables = self.database.table_names(db)
        except DatabaseError as exc:
            raise StationStoreError(f"{self.path}: not a station database ({exc})") from None
        if not tables:
            self._use_wal(db)
            if dialect == "sqlite":
                db.begin()
            for version in sorted(schema.MIGRATIONS):
                schema.apply(db, dialect, schema.MIGRATIONS[version])
            db.execute("INSERT INTO meta VALUES ('application', ?), ('schema_version', ?), "
                       "('created', ?)", (APPLICATION, str(SCHEMA_VERSION), repr(self.clock())))
            if dialect == "sqlite":
                db.commit()
            return
        meta = dict(db.execute("SELECT key, value FROM meta").fetchall()) \
            if "meta" in tables else {}
        if meta.get("application") != APPLICATION:
            raise StationStoreError(f"{self.path}: exists and is not a station database "
                                    "(refusing to change it)")
        version = int(meta.get("schema_version", "0"))
        if version > SCHEMA_VERSION:
            raise StationStoreError(f"{self.path}: schema version {version} is newer than "
                                    f"this program's ({SCHEMA_VERSION})")
        self._use_wal(db)
        if version < SCHEMA_VERSION:
            if dialect == "sqlite":
                db.begin()
            for step in range(version + 1, SCHEMA_VERSION + 1):
                schema.apply(db, dialect, schema.MIGRATIONS[step])
            db.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'",
                       (str(SCHEMA_VERSION),))
            if dialect == "sqlite":
                db.commit()

    def close(self) -> None:
        """Write what is queued (if the database allows) and close every connection."""
        if self._closed:
            return
        self.stop_writer()
        self.flush(force=True)
        self._closed = True
        with self._readers_lock:
            for db in self._readers:
                with contextlib.suppress(Exception):
                    db.close()
            self._readers.clear()
        self._writes.close()

    # ---- problems ---------------------------------------------------------------------------

    def report_problem(self, source: str, message: str) -> None:
        """Note a problem for operators (kept in memory, 200 distinct at most, with a count;
        logged once when new)."""
        self._problems.report(source, message)

    def problems(self, limit: int = 50) -> list[Problem]:
        """The most recent problems, newest first."""
        return self._problems.recent(limit)

    def clear_problem(self, source: str) -> None:
        self._problems.clear(source)

    # ---- change notification ---------------------------------------------------------------

    @property
    def sequence(self) -> int:
        """Number of committed flushes that changed something (increases monotonically)."""
        return self._feed.sequence

    def wait_for_change(self, after: int, timeout: float) -> int:
        """Block until :attr:`sequence` exceeds ``after`` or ``timeout`` passes; returns it."""
        return self._feed.wait_for_change(after, timeout)

    def subscribe(self, maxsize: int = 256) -> Subscription:
        """A new :class:`Subscription` receiving every later :class:`Change`."""
        return self._feed.subscribe(maxsize)

    def add_listener(self, callback: Callable[[Change], None]) -> Callable[[], None]:
        """Call ``callback(change)`` after each committed flush, on the writing thread (it
        must be quick: e.g. ``loop.call_soon_threadsafe``). Returns a function removing it."""
        return self._feed.add_listener(callback)

    def _notify(self, robots: frozenset[int], topics: frozenset[str]) -> None:
        self._feed.notify(robots, topics)

    # ---- queued writes (the follower's side) ----------------------------------------------

    def _queue(self, op: Op, robot: int | None, topic: str, droppable: bool = False) -> None:
        self._writes.add(op, robot, topic, droppable)

    @property
    def pending(self) -> int:
        """Changes queued and not yet committed."""
        return self._writes.pending

    @property
    def dropped_points(self) -> int:
        return self._writes.dropped_points

    @property
    def flush_times(self) -> FlushTimes:
        """How long the last committed flush took and how long its changes waited."""
        return self._writes.times

    @property
    def coalesced_points(self) -> int:
        """Chart points replaced by a newer one of their characteristic while the write
        queue was full (see :mod:`~blackbox.station.writequeue`)."""
        return self._writes.coalesced_points

    @property
    def dropped_changes(self) -> int:
        """Changes other than chart points dropped while the write queue stayed full."""
        return self._writes.dropped_changes

    def flush(self, force: bool = False) -> bool:
        """Commit everything queued in one transaction; ``True`` when what was queued when
        it was called is committed. After a failed flush the next attempt waits a second
        unless ``force``. Callable from any thread; changes queued while it writes go to
        the next flush."""
        with self._writes.flushing:
            if self._closed:
                return False
            now = self.clock()
            with self._writes.lock:
                if now - self._last_prune > 30.0 and not self._writes.pending:
                    self._queue(self._prune_op(now - self.series_retention), None, "")
                    self._last_prune = now
            committed = None
            try:
                # once taken, queued rows are written as they are: later writes of the
                # same thing are rows of their own
                committed = self._writes.flush(force, taken=self._latest.clear)
            finally:  # what the flush's status writes learnt holds once it committed
                if committed is not None:
                    self._kept_statuses.commit()
                else:
                    self._kept_statuses.discard()
        if committed is None:
            return False
        if committed.topics:
            self._notify(committed.robots, committed.topics)
        return True

    def start_writer(self) -> None:
        """Write on a thread of the store's own from now on: :meth:`flush_soon` wakes it
        and returns at once. Why: a flush waits on the database (on PostgreSQL a round trip
        per statement that reads, on a loaded machine milliseconds each), and a follower
        that flushed itself took no samples meanwhile, so they overflowed the bus's queue.
        :meth:`close` stops it after a last flush."""
        if self._writer is not None or self._closed:
            return
        self._writer_stop.clear()
        self._writer = threading.Thread(target=self._write_behind, name="station-writer",
                                        daemon=True)
        self._writer.start()

    def flush_soon(self) -> None:
        """Ask the writer thread to flush (without one: flush now)."""
        if self._writer is None:
            self.flush()
            return
        self._flush_wanted.set()

    def _write_behind(self) -> None:
        while not self._writer_stop.is_set():
            self._flush_wanted.wait(WRITER_IDLE)
            self._flush_wanted.clear()
            try:
                if not self.flush():  # failed: the queue retries after RETRY_AFTER itself
                    self._writer_stop.wait(WRITER_IDLE)
            except Exception as exc:  # keep writing whatever one flush did
                self.report_problem("store", f"writer failed: {type(exc).__name__}: {exc}")
                self._writer_stop.wait(WRITER_IDLE)

    def stop_writer(self) -> None:
        """Stop the writer thread (what is queued stays queued: flush it yourself)."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        self._writer_stop.set()
        self._flush_wanted.set()
        writer.join(timeout=30.0)

    def _prune_op(self, before: float) -> Op:
        def op(db: Connection) -> None:
            db.execute("DELETE FROM samples WHERE time < ?", (before,))
        return op

    # Robots, entities, characteristics (durable state) -----------------------------------

    def heard(self, resource_id: int, at: float) -> None:
        """A sample of robot ``resource_id`` arrived at wall time ``at``: one row per robot
        and flush, its first time and the latest (what one row per sample left)."""
        with self._writes.lock:
            queued = self._queued(("heard", resource_id))
            if queued is not None:
                rid, first, last = queued.args
                queued.args = (rid, first, max(last, at))
                return
            self._latest[("heard", resource_id)] = self._writes.add_row(
                _HEARD, (resource_id, at, at), resource_id, "fleet")

    def _queued(self, key: tuple[Any, ...]) -> PendingWrite | None:
        """The row queued for ``key`` in this flush, if it is still to be written."""
        row = self._latest.get(key)
        return None if row is None or row.gone else row

    def put_robot_id(self, resource_id: int, robot_id: str) -> None:
        rid = clip(robot_id, MAX_NAME)

        def op(db: Connection) -> None:
            now = self.clock()
            db.execute("INSERT INTO robots (resource_id, robot_id, first_heard, last_heard) "
                       "VALUES (?, ?, ?, ?) ON CONFLICT (resource_id) DO UPDATE SET "
                       "robot_id = excluded.robot_id", (resource_id, rid, now, now))
        self._queue(op, resource_id, "fleet")

    def put_entity(self, resource_id: int, instance_id: int, *, name: str | None = None,
                   kind: str | None = None, parent: int | None = None,
                   status: str | None = None, online: bool | None = None,
                   bit: bool | None = None, failures: int | None = None,
                   characteristics: Sequence[int] | None = None,
                   cause: str | None = None, actions: str | None = None,
                   updated: float | None = None) -> None:
        """Create or update an entity; ``None`` fields keep their stored value."""
        values: dict[str, Any] = {}
        if name is not None:
            values["name"] = clip(name, MAX_NAME)
        if kind is not None:
            values["kind"] = clip(kind, 20)
        if parent is not None:
            values["parent"] = parent
        if status is not None:
            values["status"] = status if status in STATUSES else "UNKNOWN"
        if online is not None:
            values["online"] = int(online)
        if bit is not None:
            values["bit"] = int(bit)
        if failures is not None:
            values["failures"] = failures
        if characteristics is not None:
            values["characteristics"] = json.dumps(list(characteristics)[:1000])
        if cause is not None:
            values["cause"] = clip(cause)
        if actions is not None:
            values["actions"] = clip(actions)
        if updated is not None:
            values["updated"] = updated
        columns = ", ".join(values)
        marks = ", ".join("?" for _ in values)
        update = ", ".join(f"{k} = excluded.{k}" for k in values) or "name = name"

        sql = (f"INSERT INTO entities (resource_id, instance_id"
               f"{', ' + columns if columns else ''}) VALUES (?, ?"
               f"{', ' + marks if marks else ''}) ON CONFLICT (resource_id, "
               f"instance_id) DO UPDATE SET {update}")
        args = (resource_id, instance_id, *values.values())
        if "status" not in values:  # a description: a row among many (see add_row)
            self._writes.add_row(sql, args, resource_id, "entities")
            return
        with self._writes.lock:  # a status: one change for a run of them (status_batch)
            batch = self._status_batch
            if batch is None or not self._writes.joins_batch(batch.apply, resource_id):
                batch = self._status_batch = EntityStatusBatch(self._kept_statuses,
                                                               self.clock)
                self._queue(batch.apply, resource_id, "entities")
            batch.add(sql, args, resource_id, instance_id, values["status"], updated)

    def put_robot_online(self, resource_id: int, online: bool) -> None:
        """A row among many (see add_row; only this statement writes ``online``), which
        creates the robot's row if its ``heard`` row is applied after it."""
        now = self.clock()
        self._writes.add_row("INSERT INTO robots (resource_id, first_heard, last_heard, "
                             "online) VALUES (?, ?, ?, ?) ON CONFLICT (resource_id) DO "
                             "UPDATE SET online = excluded.online",
                             (resource_id, now, now, int(online)), resource_id, "fleet")

    def put_diagnosis(self, resource_id: int, components: Sequence[str],
                      since: float | None) -> None:
        text = json.dumps(sorted({clip(c, MAX_NAME) for c in components}))

        def op(db: Connection) -> None:
            db.execute("UPDATE robots SET diagnosis = ?, diagnosis_since = ? "
                       "WHERE resource_id = ?", (text, since, resource_id))
        self._queue(op, resource_id, "fleet")

    def put_characteristic(self, resource_id: int, instance_id: int, *,
                           entity: int | None = None, name: str | None = None,
                           observer: str | None = None, resource: str | None = None,
                           quantity: str | None = None, unit: str | None = None,
                           expected_noise: float | None = None,
                           exceeded: bool | None = None) -> None:
        """Create or update a characteristic's description; ``None`` keeps the stored value."""
        values: dict[str, Any] = {}
        for key, value, limit in (("name", name, MAX_NAME), ("observer", observer, 60),
                                  ("resource", resource, MAX_NAME),
                                  ("quantity", quantity, 60), ("unit", unit, 20)):
            if value is not None:
                values[key] = clip(value, limit)
        if entity is not None:
            values["entity"] = entity
        if expected_noise is not None:
            values["expected_noise"] = finite(expected_noise)
        if exceeded is not None:
            values["exceeded"] = int(exceeded)
        self._upsert_characteristic(resource_id, instance_id, values)

    def put_value(self, resource_id: int, instance_id: int, t: float, value: float,
                  entity: int | None = None) -> None:
        """A new value of a characteristic: its current value and one chart point."""
        if not math.isfinite(value) or not math.isfinite(t):
            return
        values: dict[str, Any] = {"value": value, "time": t}
        if entity is not None:
            values["entity"] = entity
        sql = _characteristic_upsert(tuple(values), True)
        args = (resource_id, instance_id, *values.values())
        key = ("value", resource_id, instance_id, sql)
        with self._writes.lock:  # one current value per characteristic and flush: the newest
            queued = self._queued(key)
            if queued is not None:
                if t >= queued.args[3]:  # what the upserts' "only newer" left, in order
                    queued.args = args
            else:
                self._latest[key] = self._writes.add_row(sql, args, resource_id,
                                                         "characteristics")
        self._writes.add_row("", (resource_id, instance_id, t, value), resource_id, "",
                             droppable=True, series=(resource_id, instance_id),
                             append_to="samples")

    def _upsert_characteristic(self, resource_id: int, instance_id: int,
                               values: dict[str, Any], only_newer: bool = False) -> None:
        sql = _characteristic_upsert(tuple(values), only_newer)
        # one row among many (see WriteQueue.add_row): upserts of one characteristic set
        # other columns (a description, its flag, its newest value), so their order does
        # not matter; two of one statement keep theirs
        self._writes.add_row(sql, (resource_id, instance_id, *values.values()), resource_id,
                             "characteristics")

    def put_threshold(self, resource_id: int, instance_id: int, characteristic: int,
                      name: str, type_: str, value: float) -> None:
        if not math.isfinite(value):
            return
        args = (resource_id, instance_id, characteristic, clip(name, 60),
                "min" if type_ == "min" else "max", value)
        self._writes.add_row(
            "INSERT INTO thresholds VALUES (?, ?, ?, ?, ?, ?) ON CONFLICT (resource_id, "
            "instance_id) DO UPDATE SET characteristic = excluded.characteristic, "
            "name = excluded.name, type = excluded.type, value = excluded.value",
            args, resource_id, "characteristics")

    # Events ------------------------------------------------------------------------------

    def add_event(self, resource_id: int, t: float, kind: str, *, dedup: str,
                  entity: str = "", characteristic: str = "", text: str = "",
                  origin: str = "live", details: dict[str, Any] | None = None,
                  refers_to: int | None = None) -> None:
        """Add an event unless one with the same ``dedup`` key exists for this robot
        (the same event heard live and fetched from the log has the same key)."""
        if kind not in EVENT_KINDS:
            raise ValueError(f"unknown event kind {kind!r}")
        if origin not in ORIGINS:
            raise ValueError(f"unknown event origin {origin!r}")
        if not math.isfinite(t):
            t = self.clock()
        args = (resource_id, t, kind, clip(entity, MAX_NAME), clip(characteristic, MAX_NAME),
                clip(text), origin, clip(dedup, 400),
                json.dumps(details or {}, default=str)[:20_000], refers_to)

        def op(db: Connection) -> None:
            cur = db.execute("INSERT INTO events (resource_id, time, kind, entity, "
                             "characteristic, text, origin, dedup, details, refers_to) "
                             "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING",
                             args)
            if cur.rowcount and kind not in ("acknowledgement", "log_request", "ibit"):
                db.execute("INSERT INTO robots (resource_id, first_heard, last_heard, "
                           "last_event) VALUES (?, ?, ?, ?) ON CONFLICT (resource_id) DO "
                           "UPDATE SET last_event = greatest(coalesce(robots.last_event, 0), ?)",
                           (resource_id, t, t, t, t))
        self._queue(op, resource_id, "events")

    def name_event(self, resource_id: int, unnamed: str, t: float, kind: str, *, dedup: str,
                   entity: str = "", characteristic: str = "", text: str = "",
                   origin: str = "live", details: dict[str, Any] | None = None,
                   rewrite: bool = True) -> None:
        """A live event stored under the key ``unnamed`` (its time: its identity had not
        come) turns out to be the event ``dedup`` (its identity) names: the row is
        rewritten under ``dedup``, so the copy the robot's log supplies meets it. If the
        logged copy is stored already, the two become one: the identity's row stays and
        takes over the acknowledgement and what referred to the other (acknowledgement
        events, alerts). If no row has the key ``unnamed`` (two events of one millisecond
        stored as one, the first already named), the event is added under ``dedup``.
        ``rewrite=False`` (the identity comes with the logged copy: the extension was
        lost): a renamed row keeps what was heard live and only takes the identity
        (``details["event_id"]``). Only the event the row was stored for may name it:
        the caller knows (events of one millisecond share a time key)."""
        if kind not in EVENT_KINDS:
            raise ValueError(f"unknown event kind {kind!r}")
        if origin not in ORIGINS:
            raise ValueError(f"unknown event origin {origin!r}")
        fields = (kind, clip(entity, MAX_NAME), clip(characteristic, MAX_NAME), clip(text),
                  json.dumps(details or {}, default=str)[:20_000])
        event_id = str((details or {}).get("event_id") or "")[:40]
        new_key, old_key = clip(dedup, 400), clip(unnamed, 400)

        def op(db: Connection) -> None:
            old = db.execute("SELECT id, acknowledged_by, acknowledged_at, details FROM events "
                             "WHERE resource_id = ? AND dedup = ?",
                             (resource_id, old_key)).fetchone()
            found = db.execute("SELECT id FROM events WHERE resource_id = ? AND dedup = ?",
                               (resource_id, new_key)).fetchone()
            if old is None:
                if found is None:
                    db.execute("INSERT INTO events (resource_id, time, kind, entity, "
                               "characteristic, text, origin, dedup, details) VALUES "
                               "(?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING",
                               (resource_id, t, *fields[:4], origin, new_key, fields[4]))
                return
            if found is None and rewrite:
                db.execute("UPDATE events SET kind = ?, entity = ?, characteristic = ?, "
                           "text = ?, details = ?, dedup = ? WHERE id = ?",
                           (*fields, new_key, old[0]))
                return
            if found is None:
                kept = json.loads(old[3] or "{}")
                kept = kept if isinstance(kept, dict) else {}
                kept["event_id"] = event_id
                db.execute("UPDATE events SET dedup = ?, details = ? WHERE id = ?",
                           (new_key, json.dumps(kept, default=str)[:20_000], old[0]))
                return
            if old[1] is not None:
                db.execute("UPDATE events SET acknowledged_by = ?, acknowledged_at = ? "
                           "WHERE id = ? AND acknowledged_by IS NULL",
                           (old[1], old[2], found[0]))
            db.execute("UPDATE events SET refers_to = ? WHERE refers_to = ?",
                       (found[0], old[0]))
            db.execute("UPDATE alert_alerts SET event_id = ? WHERE event_id = ?",
                       (found[0], old[0]))
            db.execute("DELETE FROM events WHERE id = ?", (old[0],))
        self._queue(op, resource_id, "events")

    def name_entity_events(self, resource_id: int, placeholder: str, name: str,
                           texts: Mapping[str, str]) -> None:
        """Events of robot ``resource_id`` stored under the entity ``placeholder`` (its id,
        before its description came) take the entity's ``name``; one whose text is a key
        of ``texts`` (the words said with the placeholder) takes its value."""
        entity = clip(name, MAX_NAME)

        def op(db: Connection) -> None:
            for old, new in texts.items():
                db.execute("UPDATE events SET text = ? WHERE resource_id = ? AND entity = ? "
                           "AND text = ?", (clip(new), resource_id, placeholder, old))
            db.execute("UPDATE events SET entity = ? WHERE resource_id = ? AND entity = ?",
                       (entity, resource_id, placeholder))
        self._queue(op, resource_id, "events")

    def acknowledge(self, event_id: int, user: str, note: str = "") -> Event:
        """Mark event ``event_id`` acknowledged by ``user`` and add an ``acknowledgement``
        event that refers to it. Acknowledging twice keeps the first acknowledgement.
        Raises ``LookupError`` for an unknown event and :class:`StationStoreError` when the
        database cannot be written (the acknowledgement stays queued and is retried)."""
        with self._read() as db:
            row = db.execute("SELECT resource_id, kind, entity, characteristic, text "
                             "FROM events WHERE id = ?", (event_id,)).fetchone()
        if row is None:
            raise LookupError(f"no event {event_id}")
        resource_id, kind, entity, characteristic, text = row
        now = self.clock()
        who = clip(user, 100)

        def op(db: Connection) -> None:
            db.execute("UPDATE events SET acknowledged_by = ?, acknowledged_at = ? "
                       "WHERE id = ? AND acknowledged_by IS NULL", (who, now, event_id))
        self._queue(op, resource_id, "events")
        self.add_event(resource_id, now, "acknowledgement", dedup=f"ack|{event_id}",
                       entity=entity, characteristic=characteristic,
                       text=f"{who} acknowledged {kind}: {text}" + (f" ({note})" if note
                                                                     else ""),
                       origin="station", details={"note": clip(note, 500), "user": who},
                       refers_to=event_id)
        if not self.flush(force=True):
            raise StationStoreError("the station database cannot be written now; the "
                                    "acknowledgement is kept and written when it can be")
        found = self.event(event_id)
        assert found is not None
        return found

    # Log requests and IBIT (created by the follower's operations) -------------------------

    def create_log_request(self, resource_id: int, robot_id: str, *, entity: str | None,
                           characteristic: str | None, since: float | None,
                           until: float | None, kinds: Sequence[str],
                           requested_by: str) -> int:
        """A new log request record (written at once); returns its id."""
        return self._insert_now(
            "INSERT INTO log_requests (resource_id, robot_id, entity, characteristic, "
            "since, until, kinds, requested_by, created) VALUES (?,?,?,?,?,?,?,?,?)",
            (resource_id, clip(robot_id, MAX_NAME), entity, characteristic, since,
             until, json.dumps(list(kinds)), clip(requested_by, 100), self.clock()),
            resource_id, "logs", "the log request")

    def _insert_now(self, sql: str, args: Sequence[Any], resource_id: int, topic: str,
                    what: str) -> int:
        """Write one row at once (after the queue, so it is in order) and return its id:
        the caller needs the id before it answers."""
        with self._writes.flushing:
            if not self.flush(force=True):
                raise StationStoreError("the station database cannot be written now")
            try:
                row_id = self._writes.run_now(lambda db: db.insert(sql, args))
            except DatabaseError as exc:
                self.report_problem("store", f"cannot write {self.path}: {exc}")
                raise StationStoreError(f"cannot record {what}: {exc}") from None
        self._notify(frozenset({resource_id}), frozenset({topic}))
        return row_id

    def add_log_rows(self, request: int, first_seq: int, entries: Sequence[LogEntry]) -> None:
        rows = [(request, first_seq + i, e.id, e.time, clip(e.kind, 40), e.entity,
                 e.characteristic, e.code, json.dumps(e.payload, default=str))
                for i, e in enumerate(entries)]

        def op(db: Connection) -> None:
            db.executemany("INSERT INTO log_rows VALUES (?,?,?,?,?,?,?,?,?) ON CONFLICT DO NOTHING",
                           rows)
        self._queue(op, None, "")

    def update_log_request(self, request: int, resource_id: int, *, status: str,
                           rows: int, pages: int, progress: float, message: str = "",
                           finished: float | None = None) -> None:
        args = (status, clip(message, 500), rows, pages, max(0.0, min(1.0, progress)),
                finished, request)

        def op(db: Connection) -> None:
            db.execute("UPDATE log_requests SET status = ?, message = ?, rows = ?, pages = ?, "
                       "progress = ?, finished = ? WHERE id = ?", args)
        self._queue(op, resource_id, "logs")

    def create_ibit_run(self, resource_id: int, robot_id: str, entity: str,
                        requested_by: str) -> int:
        return self._insert_now(
            "INSERT INTO ibit_runs (resource_id, robot_id, entity, requested_by, created) "
            "VALUES (?,?,?,?,?)", (resource_id, clip(robot_id, MAX_NAME),
                                   clip(entity, MAX_NAME), clip(requested_by, 100),
                                   self.clock()),
            resource_id, "ibit", "the IBIT request")

    def finish_ibit_run(self, run: int, resource_id: int, *, status: str,
                        health: str | None, observations: int, failed: int,
                        report: Sequence[str]) -> None:
        args = (status, self.clock(), health, observations, failed,
                json.dumps([clip(r, 500) for r in list(report)[:1000]]), run)

        def op(db: Connection) -> None:
            db.execute("UPDATE ibit_runs SET status = ?, finished = ?, health = ?, "
                       "observations = ?, failed = ?, report = ? WHERE id = ?", args)
        self._queue(op, resource_id, "ibit")

    # ---- reads (the web's side) -------------------------------------------------------------

    def resource_of(self, robot: RobotRef) -> int:
        """The resource id of a known robot; :class:`UnknownRobot` otherwise."""
        rid = robot_resource(robot)
        with self._read() as db:
            if db.execute("SELECT 1 FROM robots WHERE resource_id = ?", (rid,)).fetchone():
                return rid
        raise UnknownRobot(f"no robot {robot!r} has been heard on this station")

    def robot_id_of(self, resource_id: int) -> str:
        with self._read() as db:
            row = db.execute("SELECT robot_id FROM robots WHERE resource_id = ?",
                             (resource_id,)).fetchone()
        return row[0] if row and row[0] else f"#{resource_id}"

    def last_event_time(self, robot: RobotRef) -> float | None:
        """Time of the newest robot event stored (failure, exceedance, ...): where a
        backfill after a restart starts."""
        with self._read() as db:
            row = db.execute("SELECT last_event FROM robots WHERE resource_id = ?",
                             (robot_resource(robot),)).fetchone()
        return None if row is None else row[0]

    def last_heard(self, robot: RobotRef) -> float | None:
        with self._read() as db:
            row = db.execute("SELECT last_heard FROM robots WHERE resource_id = ?",
                             (robot_resource(robot),)).fetchone()
        return None if row is None else row[0]

    def heard_times(self) -> list[tuple[int, str, float | None]]:
        """Every robot's resource id, robot id and last-heard time: all that watching for
        silent robots needs, twice a second, without the fleet summary's entities."""
        with self._read() as db:
            return [(int(rid), str(robot_id), last_heard) for rid, robot_id, last_heard in
                    db.execute("SELECT resource_id, robot_id, last_heard FROM robots")]

    def fleet(self, now: float | None = None) -> list[RobotSummary]:
        """Every robot ever heard, identified ones first, by name."""
        out = self._summaries(self.clock() if now is None else now, None)
        out.sort(key=lambda r: (not r.robot_id, r.name))
        return out

    def robot(self, robot: RobotRef, now: float | None = None) -> RobotSummary:
        """One robot's summary, read for that robot alone: the alert engine asks it for
        every alarm and a page for every view, and the whole fleet's summary costs
        thousands of rows at fleet scale."""
        rid = robot_resource(robot)
        found = self._summaries(self.clock() if now is None else now, rid)
        if not found:
            raise UnknownRobot(f"no robot {robot!r} has been heard on this station")
        return found[0]

    def _summaries(self, now: float, only: int | None) -> list[RobotSummary]:
        """The summaries of every robot, or of the robot with resource id ``only``."""
        where, args = ("", ()) if only is None else (" WHERE resource_id = ?", (only,))
        also = "" if only is None else " AND resource_id = ?"
        with self._read() as db:
            robots = db.execute(
                "SELECT resource_id, robot_id, last_heard, online, diagnosis FROM robots"
                + where, args).fetchall()
            # the robot's rule needs the set of its entities' statuses, the page counts:
            # grouped by the database (15,000 rows for 1,000 robots are a few thousand)
            entity_groups = db.execute(
                "SELECT resource_id, kind, status, min(online), count(*) FROM entities"
                + where + " GROUP BY resource_id, kind, status", args).fetchall()
            unacked = dict(db.execute(
                "SELECT resource_id, count(*) FROM events WHERE acknowledged_by IS NULL AND "
                "kind IN ('failure', 'exceedance')" + also + " GROUP BY resource_id",
                args).fetchall())
        per: dict[int, list[tuple[str, str, int, int]]] = {}
        for rid, kind, status, online, count in entity_groups:
            per.setdefault(rid, []).append((kind, status, online, count))
        out: list[RobotSummary] = []
        rule: dict[frozenset[str], str] = {}  # most robots share a few sets of statuses
        for rid, robot_id, last_heard, online, diagnosis in robots:
            groups = per.get(rid, [])
            reported = next((s for k, s, _, _ in groups if k == "robot"), "UNKNOWN")
            robot_online = bool(online) and all(o for k, _, o, _ in groups if k == "robot")
            stale = last_heard is None or now - last_heard > self.stale_after
            if stale or not robot_online:
                status = robot_status((), stale=stale, online=robot_online)
            else:
                statuses = frozenset(s for _, s, _, _ in groups)
                if statuses not in rule:
                    rule[statuses] = robot_status(statuses, stale=False, online=True)
                status = rule[statuses]
            failing = sum(n for k, s, _, n in groups
                          if k != "robot" and s in ("DEGRADED", "NOT_OPERATIONAL"))
            out.append(RobotSummary(
                rid, robot_id, robot_id or f"#{rid}", status, reported, last_heard, stale,
                robot_online, sum(n for _, _, _, n in groups), failing,
                int(unacked.get(rid, 0)),
                () if diagnosis == "[]" else tuple(loads(diagnosis, []))))
        return out

    def entities(self, robot: RobotRef, now: float | None = None) -> list[EntityNode]:
        """The robot's entity tree as a flat list, robot first, then by kind and name;
        ``parent`` links children to the robot entity."""
        summary = self.robot(robot, now)
        with self._read() as db:
            rows = db.execute(
                "SELECT instance_id, name, kind, status, online, bit, parent, failures, "
                "updated, characteristics FROM entities WHERE resource_id = ?",
                (summary.resource_id,)).fetchall()
        order = {"robot": 0, "node": 1, "topic": 2, "interface": 3}
        out = []
        for iid, name, kind, status, online, bit, parent, failures, updated, chars in rows:
            shown = "UNKNOWN" if summary.stale or not summary.online or not online else status
            if kind == "robot":
                shown = summary.status  # one status everywhere (station/status.py)
            out.append(EntityNode(iid, name or f"#{iid}", kind or "unknown", shown, status,
                                  bool(online), bool(bit), parent or None, failures, updated,
                                  len(loads(chars, []))))
        out.sort(key=lambda e: (order.get(e.kind, 4), e.name))
        return out

    def entity(self, robot: RobotRef, instance_id: int) -> EntityNode | None:
        return next((e for e in self.entities(robot) if e.instance_id == instance_id), None)

    def entity_by_name(self, robot: RobotRef, name: str) -> EntityNode | None:
        return next((e for e in self.entities(robot) if e.name == name), None)

    def status_track(self, robot: RobotRef, since: float, until: float) -> StatusTrack:
        """The robot's kept status changes in ``[since, until]`` (station/status_history.py)."""
        rid = self.resource_of(robot)
        with self._read() as db:
            return status_history.read(db, rid, since, until)

    def diagnosis(self, robot: RobotRef) -> Diagnosis:
        """The current diagnosis with an explanation an operator can read."""
        summary = self.robot(robot)
        with self._read() as db:
            row = db.execute("SELECT diagnosis, diagnosis_since FROM robots WHERE "
                             "resource_id = ?", (summary.resource_id,)).fetchone()
            named = set(loads(row[0], []))
            details = db.execute("SELECT name, cause, actions, status, kind FROM entities "
                                 "WHERE resource_id = ?", (summary.resource_id,)).fetchall()
        causes = {n: c for n, c, _, _, _ in details if n in named and c}
        actions = {n: a for n, _, a, _, _ in details if n in named and a}
        degraded = sorted(n for n, _, _, s, k in details
                          if k != "robot" and s == "DEGRADED" and n not in named)
        components = tuple(sorted(named))
        return Diagnosis(summary.robot_id, components,
                         explain(summary.name, components, causes, actions, degraded,
                                 stale=summary.stale, online=summary.online),
                         row[1], causes, actions)

    def characteristics(self, robot: RobotRef,
                        entity: int | None = None) -> list[Characteristic]:
        """The robot's characteristics (of one entity when ``entity`` is its instance id)."""
        rid = self.resource_of(robot)
        sql = ("SELECT c.instance_id, c.entity, coalesce(e.name, ''), c.name, c.observer, "
               "c.resource, c.quantity, c.unit, c.value, c.time, c.expected_noise, c.exceeded "
               "FROM characteristics c LEFT JOIN entities e ON e.resource_id = c.resource_id "
               "AND e.instance_id = c.entity WHERE c.resource_id = ?")
        args: list[Any] = [rid]
        if entity is not None:
            sql += " AND c.entity = ?"
            args.append(entity)
        with self._read() as db:
            rows = db.execute(sql + " ORDER BY c.name", args).fetchall()
            ths: dict[int, list[Threshold]] = {}
            for cid, name, type_, value in db.execute(
                    "SELECT characteristic, name, type, value FROM thresholds WHERE "
                    "resource_id = ? ORDER BY type DESC", (rid,)):
                ths.setdefault(cid, []).append(Threshold(name, type_, value))
        return [Characteristic(iid, ent, ename, name or f"#{iid}", obs, res, q, unit, value, t,
                               noise, tuple(ths.get(iid, ())), bool(exc))
                for iid, ent, ename, name, obs, res, q, unit, value, t, noise, exc in rows]

    def series(self, robot: RobotRef, characteristic: int, since: float | None = None,
               until: float | None = None, max_points: int = 2000) -> list[Point]:
        """Values of one characteristic, oldest first (default: the retention window),
        thinned evenly to at most ``max_points`` (capped at 5000)."""
        rid = robot_resource(robot)
        now = self.clock()
        since = now - self.series_retention if since is None else since
        until = math.inf if until is None else until
        limit = max(1, min(max_points, MAX_SERIES_POINTS))
        with self._read() as db:
            n = db.execute("SELECT count(*) FROM samples WHERE resource_id = ? AND "
                           "characteristic = ? AND time >= ? AND time <= ?",
                           (rid, characteristic, since, until)).fetchone()[0]
            step = max(1, math.ceil(n / limit))
            rows = db.execute(
                "SELECT time, value FROM (SELECT time, value, row_number() OVER "
                "(ORDER BY time) AS k FROM samples WHERE resource_id = ? AND "
                "characteristic = ? AND time >= ? AND time <= ?) AS s WHERE (k - 1) % ? = 0 "
                "ORDER BY time", (rid, characteristic, since, until, step)).fetchall()
        return [Point(t, v) for t, v in rows]

    def event(self, event_id: int) -> Event | None:
        with self._read() as db:
            row = db.execute(_EVENT_SELECT + " WHERE e.id = ?", (event_id,)).fetchone()
        return None if row is None else _event(row)

    def events(self, robot: RobotRef | None = None, *, entity: str | None = None,
               kinds: Iterable[str] | None = None, since: float | None = None,
               until: float | None = None, unacknowledged: bool = False,
               cursor: str | None = None, limit: int = 100) -> EventPage:
        """Events newest first, filtered; at most ``limit`` (1..1000) per page.

        ``robot`` unknown gives an empty page (not an error: a filter matched nothing);
        ``kinds`` outside :data:`EVENT_KINDS` raise ``ValueError``; a malformed ``cursor``
        raises ``ValueError``.
        """
        where: list[str] = []
        args: list[Any] = []
        if robot is not None:
            where.append("e.resource_id = ?")
            args.append(robot_resource(robot))
        if entity:
            where.append("e.entity = ?")
            args.append(entity)
        if kinds is not None:
            chosen = list(kinds)
            bad = [k for k in chosen if k not in EVENT_KINDS]
            if bad:
                raise ValueError(f"unknown event kind(s) {', '.join(map(repr, bad))}; "
                                 f"known: {', '.join(EVENT_KINDS)}")
            if chosen:
                where.append(f"e.kind IN ({','.join('?' for _ in chosen)})")
                args.extend(chosen)
        if since is not None:
            where.append("e.time >= ?")
            args.append(since)
        if until is not None:
            where.append("e.time <= ?")
            args.append(until)
        if unacknowledged:
            where.append("e.acknowledged_by IS NULL AND e.kind IN ('failure', 'exceedance')")
        if cursor:
            try:
                t_text, id_text = cursor.split(":", 1)
                ct, cid = float(t_text), int(id_text)
            except ValueError:
                raise ValueError(f"malformed cursor {cursor!r}") from None
            where.append("(e.time < ? OR (e.time = ? AND e.id < ?))")
            args.extend([ct, ct, cid])
        limit = max(1, min(int(limit), MAX_PAGE))
        sql = _EVENT_SELECT + (" WHERE " + " AND ".join(where) if where else "") + \
            " ORDER BY e.time DESC, e.id DESC LIMIT ?"
        with self._read() as db:
            rows = db.execute(sql, [*args, limit + 1]).fetchall()
        events = tuple(_event(r) for r in rows[:limit])
        nxt = f"{events[-1].time!r}:{events[-1].id}" if len(rows) > limit and events else None
        return EventPage(events, nxt)

    def events_after(self, after_id: int, limit: int = 500) -> list[Event]:
        """Events stored after event ``after_id``, oldest first (at most ``limit``): how a
        consumer that follows the timeline (the alert engine) reads what is new."""
        with self._read() as db:
            rows = db.execute(_EVENT_SELECT + " WHERE e.id > ? ORDER BY e.id LIMIT ?",
                              (after_id, max(1, min(limit, MAX_PAGE)))).fetchall()
        return [_event(r) for r in rows]

    def last_event_id(self) -> int:
        with self._read() as db:
            return int(db.execute("SELECT coalesce(max(id), 0) FROM events").fetchone()[0])

    def count_events(self, robot: RobotRef | None = None,
                     kinds: Iterable[str] | None = None,
                     origin: str | None = None) -> int:
        where: list[str] = []
        args: list[Any] = []
        if robot is not None:
            where.append("resource_id = ?")
            args.append(robot_resource(robot))
        chosen = list(kinds or ())
        if chosen:
            where.append(f"kind IN ({','.join('?' for _ in chosen)})")
            args.extend(chosen)
        if origin is not None:
            where.append("origin = ?")
            args.append(origin)
        with self._read() as db:
            return int(db.execute("SELECT count(*) FROM events" + (
                " WHERE " + " AND ".join(where) if where else ""), args).fetchone()[0])

    def _row(self, select: str, row_id: int) -> Sequence[Any] | None:
        with self._read() as db:
            row: Sequence[Any] | None = db.execute(select + " WHERE id = ?",
                                                   (row_id,)).fetchone()
        return row

    def _newest(self, select: str, robot: RobotRef | None, limit: int) -> list[Sequence[Any]]:
        """Rows of ``select`` newest first, of one robot or of all; at most ``limit``."""
        sql, args = select, list[Any]()
        if robot is not None:
            sql += " WHERE resource_id = ?"
            args.append(robot_resource(robot))
        with self._read() as db:
            return db.execute(sql + " ORDER BY id DESC LIMIT ?",
                              [*args, max(1, min(limit, MAX_PAGE))]).fetchall()

    def log_request(self, request: int) -> LogRequest | None:
        row = self._row(_LOG_SELECT, request)
        return None if row is None else _log_request(row)

    def log_requests(self, robot: RobotRef | None = None, limit: int = 50) -> list[LogRequest]:
        """Log requests newest first."""
        return [_log_request(r) for r in self._newest(_LOG_SELECT, robot, limit)]

    def log_entries(self, request: int, offset: int = 0,
                    limit: int = MAX_PAGE) -> list[LogEntry]:
        """Rows ``offset`` .. ``offset + limit`` (at most 1000) of a log request's answer,
        in the robot's order (entry id)."""
        with self._read() as db:
            rows = db.execute("SELECT entry_id, time, kind, entity, characteristic, code, "
                              "payload FROM log_rows WHERE request = ? AND seq >= ? "
                              "ORDER BY seq LIMIT ?",
                              (request, max(0, offset), max(1, min(limit, MAX_PAGE)))
                              ).fetchall()
        return [LogEntry(i, t, k, e, c, code, loads(p, {})) for i, t, k, e, c, code, p
                in rows]

    def iter_log_entries(self, request: int, batch: int = MAX_PAGE) -> Iterator[LogEntry]:
        """Every row of a log request's answer, read in batches (for downloads)."""
        return iter_log_entries(self, request, batch)

    def export_log(self, request: int, fmt: str, out: IO[Any]) -> int:
        """Write a log request's rows to ``out`` as ``jsonl`` or ``csv`` (text stream) or
        ``mcap`` (binary stream); returns the number of entries written."""
        return export_log(self, request, fmt, out)

    def ibit_run(self, run: int) -> IbitRun | None:
        row = self._row(_IBIT_SELECT, run)
        return None if row is None else _ibit(row)

    def ibit_runs(self, robot: RobotRef | None = None, limit: int = 50) -> list[IbitRun]:
        return [_ibit(r) for r in self._newest(_IBIT_SELECT, robot, limit)]


_EVENT_SELECT = ("SELECT e.id, e.resource_id, coalesce(r.robot_id, ''), e.time, e.kind, "
                 "e.entity, e.characteristic, e.text, e.origin, e.acknowledged_by, "
                 "e.acknowledged_at, e.refers_to, e.details FROM events e LEFT JOIN robots r "
                 "ON r.resource_id = e.resource_id")
_LOG_SELECT = ("SELECT id, resource_id, robot_id, entity, characteristic, since, until, kinds, "
               "requested_by, created, finished, status, message, rows, pages, progress "
               "FROM log_requests")
_IBIT_SELECT = ("SELECT id, resource_id, robot_id, entity, requested_by, created, finished, "
                "status, health, observations, failed, report FROM ibit_runs")


def _event(r: Sequence[Any]) -> Event:
    return Event(r[0], r[1], r[2] or f"#{r[1]}", r[3], r[4], r[5], r[6], r[7], r[8], r[9],
                 r[10], r[11], loads(r[12], {}))


def _log_request(r: Sequence[Any]) -> LogRequest:
    return LogRequest(r[0], r[1], r[2], r[3], r[4], r[5], r[6], tuple(loads(r[7], [])), r[8],
                      r[9], r[10], r[11], r[12], r[13], r[14], r[15])


def _ibit(r: Sequence[Any]) -> IbitRun:
    return IbitRun(r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10],
                   tuple(loads(r[11], [])))


if TYPE_CHECKING:
    from blackbox.station.protocols import StationDatabase

    def _implements_every_protocol(store: StationStore) -> StationDatabase:
        """Checked by mypy: the store is a complete station database."""
        return store
