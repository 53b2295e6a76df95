"""The station's own database: what it heard from every robot, kept in one SQLite file.

The station is the place where a control room looks at a fleet, so what it shows must
survive its own restarts: robots, their entity tree and statuses, characteristics with a
short time series, the event timeline, acknowledgements, log requests with their rows and
built-in test results all live in ``station.db`` (WAL, versioned schema).

Writing and reading are split for the two kinds of callers:

* the follower (``blackbox.station.follow``) *queues* changes with the ``put_*``/``add_*``
  methods from its one thread and calls :meth:`StationStore.flush` once per poll; a flush
  applies everything queued in one transaction. When the disk is full (or the file cannot
  be written for any other reason) the transaction is rolled back, the queue is kept in
  memory (bounded; the oldest time-series points go first, counted) and retried, and the
  failure is listed in :meth:`StationStore.problems`. Nothing already committed is touched.
* the web application *reads* with the typed methods below (:meth:`fleet`,
  :meth:`entities`, :meth:`diagnosis`, :meth:`characteristics`, :meth:`series`,
  :meth:`events`, :meth:`log_request`, :meth:`ibit_run`, ...) from any thread; file
  databases give every thread its own read connection so reads never wait for a write.
  :meth:`subscribe` (a bounded queue per subscriber) and :meth:`add_listener` (a callback)
  say what changed after each committed flush, for Server-Sent Events without polling.

Robots are addressed by a :data:`RobotRef`: the robot id as configured on the black box
(``"thesis-robot"``), or the UCMS resource id (an ``int``, or ``"#123"``). Every other
object is addressed by its UCMS instance id within that robot.
"""

from __future__ import annotations

import contextlib
import json
import math
import queue
import sqlite3
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from blackbox.errors import BlackBoxError
from blackbox.health.ids import robot_resource_id
from blackbox.record.store import LogEntry
from blackbox.station import status_history
from blackbox.station.status import robot_status
from blackbox.station.status_history import StatusTrack

SCHEMA_VERSION = 2
APPLICATION = "blackbox-station"

STATUSES = ("OPERATIONAL", "DEGRADED", "NOT_OPERATIONAL", "UNKNOWN")
"""UCMS health statuses, in the order of their enum values."""


EVENT_KINDS = ("failure", "rectification", "diagnosis", "exceedance", "state_change",
               "acknowledgement", "ibit", "log_request")
"""Kinds of events in the timeline.

``failure``: a diagnosis named an entity faulty (UCMS Failure Event); ``rectification``:
that entity is no longer named; ``diagnosis``: the robot's set of diagnosed entities
changed (text = the explanation in plain words); ``exceedance``: a characteristic crossed a
threshold because of a fault (UCMS Threshold Exceedance Event); ``state_change``: the same
event caused by a change between healthy states (the thesis's extension);
``acknowledgement``: an operator acknowledged an event; ``ibit``: a built-in test result;
``log_request``: an operator asked a robot for its log.
"""

ORIGINS = ("live", "log", "station")
"""Where an event came from: a DDS sample, a log request (backfill), the station itself."""

DEFAULT_STALE_AFTER = 10.0
DEFAULT_SERIES_RETENTION = 1800.0
MAX_PAGE = 1000
MAX_SERIES_POINTS = 5000
MAX_PENDING = 200_000
MAX_TEXT = 2000
MAX_NAME = 200

RobotRef = int | str
"""A robot: its robot id (``"thesis-robot"``), or its UCMS resource id (``123`` or ``"#123"``)."""


class StationStoreError(BlackBoxError):
    """The station database cannot be opened or used; the message says what and where."""


class UnknownRobot(BlackBoxError, LookupError):
    """No robot with this reference has been heard of."""


# ---- records returned to readers --------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RobotSummary:
    """One line of the fleet page.

    ``status`` is what the operator should see: the UCMS rule over the robot's entities
    (:func:`blackbox.station.status.robot_status`), or ``UNKNOWN`` when the robot is
    ``stale`` (silent for longer than ``stale_after``) or ``offline`` (its black box said
    it stopped). ``reported_status`` is the robot entity's own UCMS status as last received.
    """

    resource_id: int
    robot_id: str
    name: str
    status: str
    reported_status: str
    last_heard: float | None
    stale: bool
    online: bool
    entities: int
    failing: int
    unacknowledged: int
    diagnosis: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class EntityNode:
    """One monitored entity: the robot itself (kind ``robot``), a node, a topic, or
    hardware (kind ``interface``). ``parent`` is the instance id of the parent entity
    (``None`` for the robot). ``status`` is ``UNKNOWN`` while the robot is stale;
    ``reported_status`` is what the black box last said."""

    instance_id: int
    name: str
    kind: str
    status: str
    reported_status: str
    online: bool
    bit_in_progress: bool
    parent: int | None
    failures: int
    updated: float | None
    characteristics: int


@dataclass(frozen=True, slots=True)
class Threshold:
    name: str
    type: str  # "min" or "max"
    value: float


@dataclass(frozen=True, slots=True)
class Characteristic:
    """A monitored characteristic with its latest value (``None`` before the first)."""

    instance_id: int
    entity: int | None
    entity_name: str
    name: str
    observer: str
    resource: str
    quantity: str
    unit: str
    value: float | None
    time: float | None
    expected_noise: float | None
    thresholds: tuple[Threshold, ...]
    exceeded: bool


@dataclass(frozen=True, slots=True)
class Point:
    time: float
    value: float


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """The robot's current diagnosis: the entities named faulty, and why, in plain words."""

    robot_id: str
    components: tuple[str, ...]
    explanation: str
    since: float | None
    causes: dict[str, str]
    actions: dict[str, str]


@dataclass(frozen=True, slots=True)
class Event:
    id: int
    resource_id: int
    robot_id: str
    time: float
    kind: str
    entity: str
    characteristic: str
    text: str
    origin: str
    acknowledged_by: str | None
    acknowledged_at: float | None
    refers_to: int | None
    details: dict[str, Any]


@dataclass(frozen=True, slots=True)
class EventPage:
    """Events newest first; pass ``next_cursor`` back as ``cursor`` for the next page
    (``None``: this was the last page)."""

    events: tuple[Event, ...]
    next_cursor: str | None


@dataclass(frozen=True, slots=True)
class Problem:
    """Something the station could not do or would not accept; shown to operators."""

    source: str
    message: str
    first: float
    last: float
    count: int


@dataclass(frozen=True, slots=True)
class LogRequest:
    """A request for a robot's log and how far it got.

    ``status``: ``pending``, ``running``, ``done``, ``error``, ``timeout`` or ``truncated``
    (stopped at ``max_rows``). ``progress`` is 0..1 (time covered of the range asked for).
    """

    id: int
    resource_id: int
    robot_id: str
    entity: str | None
    characteristic: str | None
    since: float | None
    until: float | None
    kinds: tuple[str, ...]
    requested_by: str
    created: float
    finished: float | None
    status: str
    message: str
    rows: int
    pages: int
    progress: float


@dataclass(frozen=True, slots=True)
class IbitRun:
    """A built-in test asked of a robot; ``status`` ``pending``, ``done`` or ``timeout``."""

    id: int
    resource_id: int
    robot_id: str
    entity: str
    requested_by: str
    created: float
    finished: float | None
    status: str
    health: str | None
    observations: int
    failed: int
    report: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Change:
    """What one committed flush changed: ``seq`` increases by one per flush; ``robots``
    are resource ids; ``topics`` name what changed (``fleet``, ``entities``,
    ``characteristics``, ``events``, ``logs``, ``ibit``, ``problems``). ``overflow`` is set
    on the first change a slow subscriber sees after changes were dropped for it: reload."""

    seq: int
    time: float
    robots: frozenset[int]
    topics: frozenset[str]
    overflow: bool = False


class Subscription:
    """A bounded, thread-safe queue of :class:`Change` for one subscriber.

    ``get(timeout)`` returns the next change or ``None`` on timeout. When the subscriber
    falls ``maxsize`` changes behind, older changes are dropped and the next one returned
    has ``overflow`` set. ``close()`` (or leaving a ``with`` block) unsubscribes.
    """

    def __init__(self, store: StationStore, maxsize: int) -> None:
        self._store = store
        self._queue: queue.Queue[Change] = queue.Queue(maxsize=max(1, maxsize))
        self._overflow = False
        self._lock = threading.Lock()

    def _offer(self, change: Change) -> None:
        with self._lock:
            if self._overflow:
                change = Change(change.seq, change.time, change.robots, change.topics, True)
            try:
                self._queue.put_nowait(change)
                self._overflow = False
            except queue.Full:
                with contextlib.suppress(queue.Empty):
                    self._queue.get_nowait()
                self._queue.put_nowait(Change(change.seq, change.time, change.robots,
                                              change.topics, True))

    def get(self, timeout: float | None = None) -> Change | None:
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        self._store._unsubscribe(self)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---- schema -----------------------------------------------------------------------------------


_SCHEMA_V1 = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE robots (
    resource_id INTEGER PRIMARY KEY,
    robot_id TEXT NOT NULL DEFAULT '',
    first_heard REAL NOT NULL,
    last_heard REAL NOT NULL,
    last_event REAL,
    online INTEGER NOT NULL DEFAULT 1,
    diagnosis TEXT NOT NULL DEFAULT '[]',
    diagnosis_since REAL
);
CREATE TABLE entities (
    resource_id INTEGER NOT NULL,
    instance_id INTEGER NOT NULL,
    name TEXT NOT NULL DEFAULT '',
    kind TEXT NOT NULL DEFAULT '',
    parent INTEGER,
    status TEXT NOT NULL DEFAULT 'UNKNOWN',
    online INTEGER NOT NULL DEFAULT 1,
    bit INTEGER NOT NULL DEFAULT 0,
    failures INTEGER NOT NULL DEFAULT 0,
    cause TEXT NOT NULL DEFAULT '',
    actions TEXT NOT NULL DEFAULT '',
    characteristics TEXT NOT NULL DEFAULT '[]',
    updated REAL,
    PRIMARY KEY (resource_id, instance_id)
);
CREATE TABLE characteristics (
    resource_id INTEGER NOT NULL,
    instance_id INTEGER NOT NULL,
    entity INTEGER,
    name TEXT NOT NULL DEFAULT '',
    observer TEXT NOT NULL DEFAULT '',
    resource TEXT NOT NULL DEFAULT '',
    quantity TEXT NOT NULL DEFAULT '',
    unit TEXT NOT NULL DEFAULT '',
    value REAL,
    time REAL,
    expected_noise REAL,
    exceeded INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (resource_id, instance_id)
);
CREATE TABLE thresholds (
    resource_id INTEGER NOT NULL,
    instance_id INTEGER NOT NULL,
    characteristic INTEGER NOT NULL,
    name TEXT NOT NULL,
    type TEXT NOT NULL,
    value REAL NOT NULL,
    PRIMARY KEY (resource_id, instance_id)
);
CREATE INDEX thresholds_characteristic ON thresholds (resource_id, characteristic);
CREATE TABLE samples (
    resource_id INTEGER NOT NULL,
    characteristic INTEGER NOT NULL,
    time REAL NOT NULL,
    value REAL NOT NULL
);
CREATE INDEX samples_series ON samples (resource_id, characteristic, time);
CREATE INDEX samples_time ON samples (time);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    resource_id INTEGER NOT NULL,
    time REAL NOT NULL,
    kind TEXT NOT NULL,
    entity TEXT NOT NULL DEFAULT '',
    characteristic TEXT NOT NULL DEFAULT '',
    text TEXT NOT NULL DEFAULT '',
    origin TEXT NOT NULL,
    dedup TEXT NOT NULL,
    details TEXT NOT NULL DEFAULT '{}',
    acknowledged_by TEXT,
    acknowledged_at REAL,
    refers_to INTEGER,
    UNIQUE (resource_id, dedup)
);
CREATE INDEX events_time ON events (time, id);
CREATE INDEX events_robot_time ON events (resource_id, time, id);
CREATE TABLE log_requests (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    resource_id INTEGER NOT NULL,
    robot_id TEXT NOT NULL,
    entity TEXT,
    characteristic TEXT,
    since REAL,
    until REAL,
    kinds TEXT NOT NULL DEFAULT '[]',
    requested_by TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL,
    finished REAL,
    status TEXT NOT NULL DEFAULT 'pending',
    message TEXT NOT NULL DEFAULT '',
    rows INTEGER NOT NULL DEFAULT 0,
    pages INTEGER NOT NULL DEFAULT 0,
    progress REAL NOT NULL DEFAULT 0
);
CREATE TABLE log_rows (
    request INTEGER NOT NULL REFERENCES log_requests(id) ON DELETE CASCADE,
    seq INTEGER NOT NULL,
    entry_id INTEGER NOT NULL,
    time REAL NOT NULL,
    kind TEXT NOT NULL,
    entity TEXT,
    characteristic TEXT,
    code INTEGER,
    payload TEXT NOT NULL,
    PRIMARY KEY (request, seq)
);
CREATE TABLE ibit_runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    resource_id INTEGER NOT NULL,
    robot_id TEXT NOT NULL,
    entity TEXT NOT NULL DEFAULT '',
    requested_by TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL,
    finished REAL,
    status TEXT NOT NULL DEFAULT 'pending',
    health TEXT,
    observations INTEGER NOT NULL DEFAULT 0,
    failed INTEGER NOT NULL DEFAULT 0,
    report TEXT NOT NULL DEFAULT '[]'
)
"""


def _clip(text: object, limit: int = MAX_TEXT) -> str:
    s = str(text)
    return s if len(s) <= limit else s[: limit - 1] + "…"


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _loads(text: str, default: Any) -> Any:
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        return default


def robot_resource(robot: RobotRef) -> int:
    """The UCMS resource id of a :data:`RobotRef` (the robot id's hash, see health/ids)."""
    if isinstance(robot, int):
        return robot
    if robot.startswith("#") and robot[1:].isdigit():
        return int(robot[1:])
    return robot_resource_id(robot)


_Op = Callable[[sqlite3.Connection], None]


@dataclass(slots=True)
class _Pending:
    op: _Op
    robot: int | None
    topic: str
    droppable: bool = False


@dataclass(slots=True)
class _ProblemState:
    source: str
    message: str
    first: float
    last: float
    count: int = 1


class StationStore:
    """The station database at ``path`` (``":memory:"`` for a throw-away one, as
    ``blackbox listen`` uses).

    ``stale_after``: seconds of silence after which a robot is shown ``UNKNOWN``.
    ``series_retention``: seconds of characteristic values kept for charts.
    ``clock``: wall-clock seconds (tests pass their own).
    Open it with :meth:`open` (creates or migrates the schema; a file that is not a
    station database is refused with :class:`StationStoreError`), close it with
    :meth:`close`.
    """

    def __init__(self, path: str | Path, *, stale_after: float = DEFAULT_STALE_AFTER,
                 series_retention: float = DEFAULT_SERIES_RETENTION,
                 max_pending: int = MAX_PENDING,
                 clock: Callable[[], float] = time.time) -> None:
        if stale_after <= 0 or series_retention <= 0:
            raise ValueError("stale_after and series_retention must be positive")
        self.path = str(path)
        self.memory = self.path == ":memory:"
        self.stale_after = stale_after
        self.series_retention = series_retention
        self.max_pending = max_pending
        self.clock = clock
        self._write_lock = threading.RLock()
        self._pending: deque[_Pending] = deque()
        self._dropped_points = 0
        self._local = threading.local()
        self._readers: list[sqlite3.Connection] = []
        self._readers_lock = threading.Lock()
        self._subscribers: list[Subscription] = []
        self._listeners: list[Callable[[Change], None]] = []
        self._notify_lock = threading.Lock()
        self._seq = 0
        self._seq_cond = threading.Condition()
        self._problems: dict[tuple[str, str], _ProblemState] = {}
        self._problems_lock = threading.Lock()
        self._last_prune = 0.0
        self._last_failed_flush = -math.inf
        self._closed = False
        self._db = self._connect()
        try:
            self._migrate()
        except (StationStoreError, sqlite3.Error) as exc:
            self._db.close()
            if isinstance(exc, StationStoreError):
                raise
            raise StationStoreError(f"{self.path}: cannot use the station database: "
                                    f"{exc}") from None

    @classmethod
    def open(cls, path: str | Path = "station.db", **kwargs: Any) -> StationStore:
        return cls(path, **kwargs)

    # ---- connections ------------------------------------------------------------------------

    def _connect(self) -> sqlite3.Connection:
        try:
            if not self.memory:
                parent = Path(self.path).parent
                if not parent.is_dir():
                    raise StationStoreError(f"{self.path}: directory {parent} does not exist")
            db = sqlite3.connect(self.path, timeout=10.0, check_same_thread=False,
                                 isolation_level=None)
            db.execute("PRAGMA foreign_keys=ON")
            return db
        except sqlite3.DatabaseError as exc:
            raise StationStoreError(f"{self.path}: cannot open the station database: "
                                    f"{exc}") from None

    def _use_wal(self) -> None:
        if self.memory:
            return
        mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            raise StationStoreError(f"{self.path}: cannot use WAL mode ({mode})")
        self._db.execute("PRAGMA synchronous=NORMAL")

    def _reader(self) -> sqlite3.Connection:
        if self.memory:
            return self._db
        db: sqlite3.Connection | None = getattr(self._local, "db", None)
        if db is None:
            try:
                db = sqlite3.connect(f"file:{Path(self.path).resolve()}?mode=ro", uri=True,
                                     timeout=10.0, check_same_thread=False)
            except sqlite3.DatabaseError as exc:
                raise StationStoreError(f"{self.path}: cannot read: {exc}") from None
            self._local.db = db
            with self._readers_lock:
                self._readers.append(db)
        return db

    @contextlib.contextmanager
    def _read(self) -> Iterator[sqlite3.Connection]:
        if self.memory:
            with self._write_lock:
                yield self._db
        else:
            yield self._reader()

    def _migrate(self) -> None:
        db = self._db
        try:
            tables = {r[0] for r in db.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
        except sqlite3.DatabaseError as exc:
            raise StationStoreError(f"{self.path}: not a station database ({exc})") from None
        if not tables:
            self._use_wal()
            db.execute("BEGIN")
            for statement in _SCHEMA_V1.split(";"):
                if statement.strip():
                    db.execute(statement)
            status_history.create(db)
            db.execute("INSERT INTO meta VALUES ('application', ?), ('schema_version', ?), "
                       "('created', ?)", (APPLICATION, str(SCHEMA_VERSION), repr(self.clock())))
            db.execute("COMMIT")
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
        self._use_wal()
        if version < 2:  # version 2 added the status history (station/status_history.py)
            db.execute("BEGIN IMMEDIATE")
            status_history.create(db)
            db.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'",
                       (str(SCHEMA_VERSION),))
            db.execute("COMMIT")

    def close(self) -> None:
        """Write what is queued (if the disk allows) and close every connection."""
        if self._closed:
            return
        self.flush(force=True)
        self._closed = True
        with self._readers_lock:
            for db in self._readers:
                with contextlib.suppress(sqlite3.Error):
                    db.close()
            self._readers.clear()
        with self._write_lock:
            self._db.close()

    # ---- problems ---------------------------------------------------------------------------

    def report_problem(self, source: str, message: str) -> None:
        """Note a problem for operators (kept in memory, 200 distinct at most, with a count)."""
        now = self.clock()
        key = (_clip(source, 100), _clip(message, 500))
        with self._problems_lock:
            p = self._problems.get(key)
            if p is None:
                if len(self._problems) >= 200:
                    oldest = min(self._problems, key=lambda k: self._problems[k].last)
                    del self._problems[oldest]
                self._problems[key] = _ProblemState(key[0], key[1], now, now)
                new = True
            else:
                p.last = now
                p.count += 1
                new = False
        if new:
            self._notify(frozenset(), frozenset({"problems"}))

    def problems(self, limit: int = 50) -> list[Problem]:
        """The most recent problems, newest first."""
        with self._problems_lock:
            items = sorted(self._problems.values(), key=lambda p: p.last, reverse=True)
        return [Problem(p.source, p.message, p.first, p.last, p.count)
                for p in items[: max(0, limit)]]

    def clear_problem(self, source: str) -> None:
        with self._problems_lock:
            for key in [k for k in self._problems if k[0] == source]:
                del self._problems[key]

    # ---- change notification ---------------------------------------------------------------

    @property
    def sequence(self) -> int:
        """Number of committed flushes that changed something (increases monotonically)."""
        return self._seq

    def wait_for_change(self, after: int, timeout: float) -> int:
        """Block until :attr:`sequence` exceeds ``after`` or ``timeout`` passes; returns it."""
        with self._seq_cond:
            self._seq_cond.wait_for(lambda: self._seq > after, timeout=max(0.0, timeout))
            return self._seq

    def subscribe(self, maxsize: int = 256) -> Subscription:
        """A new :class:`Subscription` receiving every later :class:`Change`."""
        sub = Subscription(self, maxsize)
        with self._notify_lock:
            self._subscribers.append(sub)
        return sub

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._notify_lock, contextlib.suppress(ValueError):
            self._subscribers.remove(sub)

    def add_listener(self, callback: Callable[[Change], None]) -> Callable[[], None]:
        """Call ``callback(change)`` after each committed flush, on the writing thread (it
        must be quick: e.g. ``loop.call_soon_threadsafe``). Returns a function removing it."""
        with self._notify_lock:
            self._listeners.append(callback)

        def remove() -> None:
            with self._notify_lock, contextlib.suppress(ValueError):
                self._listeners.remove(callback)
        return remove

    def _notify(self, robots: frozenset[int], topics: frozenset[str]) -> None:
        with self._seq_cond:
            self._seq += 1
            change = Change(self._seq, self.clock(), robots, topics)
            self._seq_cond.notify_all()
        with self._notify_lock:
            subscribers = list(self._subscribers)
            listeners = list(self._listeners)
        for sub in subscribers:
            sub._offer(change)
        for callback in listeners:
            try:
                callback(change)
            except Exception as exc:  # a broken listener must not stop ingestion
                self.report_problem("notify", f"change listener failed: {exc}")

    # ---- queued writes (the follower's side) ----------------------------------------------

    def _queue(self, op: _Op, robot: int | None, topic: str, droppable: bool = False) -> None:
        with self._write_lock:
            self._pending.append(_Pending(op, robot, topic, droppable))
            if len(self._pending) > self.max_pending:
                self._shed()

    def _shed(self) -> None:
        """Over the bound: drop queued time-series points first (counted), then refuse the
        oldest of anything else (counted as a problem)."""
        kept: deque[_Pending] = deque()
        excess = len(self._pending) - self.max_pending // 2
        for item in self._pending:
            if excess > 0 and item.droppable:
                excess -= 1
                self._dropped_points += 1
                continue
            kept.append(item)
        while len(kept) > self.max_pending:
            kept.popleft()
            self.report_problem("store", "write queue full while the database cannot be "
                                         "written: oldest queued changes dropped")
        self._pending = kept
        self.report_problem("store", f"database not writable: {self._dropped_points} chart "
                                     "points dropped so far (state and events are kept)")

    @property
    def pending(self) -> int:
        """Changes queued and not yet committed."""
        return len(self._pending)

    @property
    def dropped_points(self) -> int:
        return self._dropped_points

    def flush(self, force: bool = False) -> bool:
        """Commit everything queued in one transaction; ``True`` when the queue is empty
        afterwards. After a failed flush the next attempt waits a second unless ``force``."""
        with self._write_lock:
            if self._closed:
                return False
            now = self.clock()
            if not force and now - self._last_failed_flush < 1.0 and self._pending:
                return False
            if now - self._last_prune > 30.0 and not self._pending:
                self._queue(self._prune_op(now - self.series_retention), None, "")
                self._last_prune = now
            if not self._pending:
                return True
            batch = list(self._pending)
            db = self._db
            try:
                db.execute("BEGIN IMMEDIATE")
                for item in batch:
                    item.op(db)
                db.execute("COMMIT")
            except sqlite3.Error as exc:
                with contextlib.suppress(sqlite3.Error):
                    db.execute("ROLLBACK")
                self._last_failed_flush = now
                self.report_problem("store", f"cannot write {self.path}: {exc} "
                                             f"({len(batch)} changes kept in memory, retried)")
                return False
            if self._last_failed_flush > -math.inf:
                self._last_failed_flush = -math.inf
                self.clear_problem("store")
                self.report_problem("store-recovered", f"{self.path} writable again")
            for _ in batch:
                self._pending.popleft()
        robots = frozenset(i.robot for i in batch if i.robot is not None)
        topics = frozenset(i.topic for i in batch if i.topic)
        if topics:
            self._notify(robots, topics)
        return True

    def _prune_op(self, before: float) -> _Op:
        def op(db: sqlite3.Connection) -> None:
            db.execute("DELETE FROM samples WHERE time < ?", (before,))
        return op

    # Robots, entities, characteristics (durable state) -----------------------------------

    def heard(self, resource_id: int, at: float) -> None:
        """A sample of robot ``resource_id`` arrived at wall time ``at``."""
        def op(db: sqlite3.Connection) -> None:
            db.execute("INSERT INTO robots (resource_id, first_heard, last_heard) "
                       "VALUES (?, ?, ?) ON CONFLICT (resource_id) DO UPDATE SET "
                       "last_heard = max(last_heard, excluded.last_heard)",
                       (resource_id, at, at))
        self._queue(op, resource_id, "fleet")

    def put_robot_id(self, resource_id: int, robot_id: str) -> None:
        rid = _clip(robot_id, MAX_NAME)

        def op(db: sqlite3.Connection) -> None:
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
            values["name"] = _clip(name, MAX_NAME)
        if kind is not None:
            values["kind"] = _clip(kind, 20)
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
            values["cause"] = _clip(cause)
        if actions is not None:
            values["actions"] = _clip(actions)
        if updated is not None:
            values["updated"] = updated
        columns = ", ".join(values)
        marks = ", ".join("?" for _ in values)
        update = ", ".join(f"{k} = excluded.{k}" for k in values) or "name = name"

        def op(db: sqlite3.Connection) -> None:
            db.execute(f"INSERT INTO entities (resource_id, instance_id"
                       f"{', ' + columns if columns else ''}) VALUES (?, ?"
                       f"{', ' + marks if marks else ''}) ON CONFLICT (resource_id, "
                       f"instance_id) DO UPDATE SET {update}",
                       (resource_id, instance_id, *values.values()))
            if status is not None:
                status_history.note(db, resource_id, instance_id, values["status"],
                                    self.clock() if updated is None else updated)
        self._queue(op, resource_id, "entities")

    def put_robot_online(self, resource_id: int, online: bool) -> None:
        def op(db: sqlite3.Connection) -> None:
            db.execute("UPDATE robots SET online = ? WHERE resource_id = ?",
                       (int(online), resource_id))
        self._queue(op, resource_id, "fleet")

    def put_diagnosis(self, resource_id: int, components: Sequence[str],
                      since: float | None) -> None:
        text = json.dumps(sorted({_clip(c, MAX_NAME) for c in components}))

        def op(db: sqlite3.Connection) -> None:
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
                values[key] = _clip(value, limit)
        if entity is not None:
            values["entity"] = entity
        if expected_noise is not None:
            values["expected_noise"] = _finite(expected_noise)
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
        self._upsert_characteristic(resource_id, instance_id, values, only_newer=True)

        def op(db: sqlite3.Connection) -> None:
            db.execute("INSERT INTO samples VALUES (?, ?, ?, ?)",
                       (resource_id, instance_id, t, value))
        self._queue(op, resource_id, "", droppable=True)

    def _upsert_characteristic(self, resource_id: int, instance_id: int,
                               values: dict[str, Any], only_newer: bool = False) -> None:
        columns = "".join(f", {k}" for k in values)
        marks = "".join(", ?" for _ in values)
        update = ", ".join(f"{k} = excluded.{k}" for k in values) or "name = name"
        where = " WHERE characteristics.time IS NULL OR characteristics.time <= excluded.time" \
            if only_newer else ""

        def op(db: sqlite3.Connection) -> None:
            db.execute(f"INSERT INTO characteristics (resource_id, instance_id{columns}) "
                       f"VALUES (?, ?{marks}) ON CONFLICT (resource_id, instance_id) DO "
                       f"UPDATE SET {update}{where}",
                       (resource_id, instance_id, *values.values()))
        self._queue(op, resource_id, "characteristics")

    def put_threshold(self, resource_id: int, instance_id: int, characteristic: int,
                      name: str, type_: str, value: float) -> None:
        if not math.isfinite(value):
            return
        args = (resource_id, instance_id, characteristic, _clip(name, 60),
                "min" if type_ == "min" else "max", value)

        def op(db: sqlite3.Connection) -> None:
            db.execute("INSERT OR REPLACE INTO thresholds VALUES (?, ?, ?, ?, ?, ?)", args)
        self._queue(op, resource_id, "characteristics")

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
        args = (resource_id, t, kind, _clip(entity, MAX_NAME), _clip(characteristic, MAX_NAME),
                _clip(text), origin, _clip(dedup, 400),
                json.dumps(details or {}, default=str)[:20_000], refers_to)

        def op(db: sqlite3.Connection) -> None:
            cur = db.execute("INSERT OR IGNORE INTO events (resource_id, time, kind, entity, "
                             "characteristic, text, origin, dedup, details, refers_to) "
                             "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", args)
            if cur.rowcount and kind not in ("acknowledgement", "log_request", "ibit"):
                db.execute("INSERT INTO robots (resource_id, first_heard, last_heard, "
                           "last_event) VALUES (?, ?, ?, ?) ON CONFLICT (resource_id) DO "
                           "UPDATE SET last_event = max(coalesce(last_event, 0), ?)",
                           (resource_id, t, t, t, t))
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
        who = _clip(user, 100)

        def op(db: sqlite3.Connection) -> None:
            db.execute("UPDATE events SET acknowledged_by = ?, acknowledged_at = ? "
                       "WHERE id = ? AND acknowledged_by IS NULL", (who, now, event_id))
        self._queue(op, resource_id, "events")
        self.add_event(resource_id, now, "acknowledgement", dedup=f"ack|{event_id}",
                       entity=entity, characteristic=characteristic,
                       text=f"{who} acknowledged {kind}: {text}" + (f" ({note})" if note
                                                                     else ""),
                       origin="station", details={"note": _clip(note, 500), "user": who},
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
            (resource_id, _clip(robot_id, MAX_NAME), entity, characteristic, since,
             until, json.dumps(list(kinds)), _clip(requested_by, 100), self.clock()),
            resource_id, "logs", "the log request")

    def _insert_now(self, sql: str, args: Sequence[Any], resource_id: int, topic: str,
                    what: str) -> int:
        """Write one row at once (after the queue, so it is in order) and return its id:
        the caller needs the id before it answers."""
        with self._write_lock:
            if not self.flush(force=True):
                raise StationStoreError("the station database cannot be written now")
            try:
                cur = self._db.execute(sql, args)
            except sqlite3.Error as exc:
                self.report_problem("store", f"cannot write {self.path}: {exc}")
                raise StationStoreError(f"cannot record {what}: {exc}") from None
            assert cur.lastrowid is not None
            row_id = int(cur.lastrowid)
        self._notify(frozenset({resource_id}), frozenset({topic}))
        return row_id

    def add_log_rows(self, request: int, first_seq: int, entries: Sequence[LogEntry]) -> None:
        rows = [(request, first_seq + i, e.id, e.time, _clip(e.kind, 40), e.entity,
                 e.characteristic, e.code, json.dumps(e.payload, default=str))
                for i, e in enumerate(entries)]

        def op(db: sqlite3.Connection) -> None:
            db.executemany("INSERT OR IGNORE INTO log_rows VALUES (?,?,?,?,?,?,?,?,?)", rows)
        self._queue(op, None, "")

    def update_log_request(self, request: int, resource_id: int, *, status: str,
                           rows: int, pages: int, progress: float, message: str = "",
                           finished: float | None = None) -> None:
        args = (status, _clip(message, 500), rows, pages, max(0.0, min(1.0, progress)),
                finished, request)

        def op(db: sqlite3.Connection) -> None:
            db.execute("UPDATE log_requests SET status = ?, message = ?, rows = ?, pages = ?, "
                       "progress = ?, finished = ? WHERE id = ?", args)
        self._queue(op, resource_id, "logs")

    def create_ibit_run(self, resource_id: int, robot_id: str, entity: str,
                        requested_by: str) -> int:
        return self._insert_now(
            "INSERT INTO ibit_runs (resource_id, robot_id, entity, requested_by, created) "
            "VALUES (?,?,?,?,?)", (resource_id, _clip(robot_id, MAX_NAME),
                                   _clip(entity, MAX_NAME), _clip(requested_by, 100),
                                   self.clock()),
            resource_id, "ibit", "the IBIT request")

    def finish_ibit_run(self, run: int, resource_id: int, *, status: str,
                        health: str | None, observations: int, failed: int,
                        report: Sequence[str]) -> None:
        args = (status, self.clock(), health, observations, failed,
                json.dumps([_clip(r, 500) for r in list(report)[:1000]]), run)

        def op(db: sqlite3.Connection) -> None:
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

    def fleet(self, now: float | None = None) -> list[RobotSummary]:
        """Every robot ever heard, identified ones first, by name."""
        now = self.clock() if now is None else now
        with self._read() as db:
            robots = db.execute(
                "SELECT resource_id, robot_id, last_heard, online, diagnosis FROM robots"
            ).fetchall()
            entity_rows = db.execute(
                "SELECT resource_id, kind, status, online, failures FROM entities").fetchall()
            unacked = dict(db.execute(
                "SELECT resource_id, count(*) FROM events WHERE acknowledged_by IS NULL AND "
                "kind IN ('failure', 'exceedance') GROUP BY resource_id").fetchall())
        per: dict[int, list[tuple[str, str, int, int]]] = {}
        for rid, kind, status, online, failures in entity_rows:
            per.setdefault(rid, []).append((kind, status, online, failures))
        out: list[RobotSummary] = []
        for rid, robot_id, last_heard, online, diagnosis in robots:
            ents = per.get(rid, [])
            reported = next((s for k, s, _, _ in ents if k == "robot"), "UNKNOWN")
            robot_online = bool(online) and all(o for k, _, o, _ in ents if k == "robot")
            stale = last_heard is None or now - last_heard > self.stale_after
            status = robot_status((s for _, s, _, _ in ents), stale=stale,
                                  online=robot_online)
            failing = sum(1 for k, s, _, _ in ents
                          if k != "robot" and s in ("DEGRADED", "NOT_OPERATIONAL"))
            out.append(RobotSummary(
                rid, robot_id, robot_id or f"#{rid}", status, reported, last_heard, stale,
                robot_online, len(ents), failing, int(unacked.get(rid, 0)),
                tuple(_loads(diagnosis, []))))
        out.sort(key=lambda r: (not r.robot_id, r.name))
        return out

    def robot(self, robot: RobotRef, now: float | None = None) -> RobotSummary:
        rid = self.resource_of(robot)
        for summary in self.fleet(now):
            if summary.resource_id == rid:
                return summary
        raise UnknownRobot(f"no robot {robot!r}")

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
                                  len(_loads(chars, []))))
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
            named = set(_loads(row[0], []))
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
                "characteristic = ? AND time >= ? AND time <= ?) WHERE (k - 1) % ? = 0 "
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
        return [LogEntry(i, t, k, e, c, code, _loads(p, {})) for i, t, k, e, c, code, p
                in rows]

    def iter_log_entries(self, request: int, batch: int = MAX_PAGE) -> Iterator[LogEntry]:
        """Every row of a log request's answer, read in batches (for downloads)."""
        offset = 0
        while True:
            entries = self.log_entries(request, offset, batch)
            if not entries:
                return
            yield from entries
            offset += len(entries)

    def export_log(self, request: int, fmt: str, out: IO[Any]) -> int:
        """Write a log request's rows to ``out`` as ``jsonl`` or ``csv`` (text stream) or
        ``mcap`` (binary stream); returns the number of entries written."""
        from blackbox.record.export import FORMATS, write_csv, write_jsonl, write_mcap

        info = self.log_request(request)
        if info is None:
            raise LookupError(f"no log request {request}")
        if fmt not in FORMATS:
            raise ValueError(f"unknown format {fmt!r}; use one of {', '.join(FORMATS)}")
        entries = self.iter_log_entries(request)
        if fmt == "mcap":
            return write_mcap(entries, out, info.robot_id)
        return (write_jsonl if fmt == "jsonl" else write_csv)(entries, out)

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
                 r[10], r[11], _loads(r[12], {}))


def _log_request(r: Sequence[Any]) -> LogRequest:
    return LogRequest(r[0], r[1], r[2], r[3], r[4], r[5], r[6], tuple(_loads(r[7], [])), r[8],
                      r[9], r[10], r[11], r[12], r[13], r[14], r[15])


def _ibit(r: Sequence[Any]) -> IbitRun:
    return IbitRun(r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10],
                   tuple(_loads(r[11], [])))


def explain(robot: str, components: Sequence[str], causes: dict[str, str],
            actions: dict[str, str], degraded: Sequence[str] = (), *, stale: bool = False,
            online: bool = True) -> str:
    """The current diagnosis in words an operator reads at a glance."""
    parts: list[str] = []
    if not online:
        parts.append(f"{robot}'s black box has stopped; what is shown is its last state.")
    elif stale:
        parts.append(f"{robot} has not been heard for a while; what is shown is its last "
                     "known state and may be out of date.")
    if components:
        names = ", ".join(components)
        verb = "is" if len(components) == 1 else "are"
        parts.append(f"The black box diagnoses {names}: {names} {verb} not working.")
        for name in components:
            if causes.get(name):
                parts.append(f"{name}: {causes[name]}.")
            if actions.get(name):
                parts.append(f"What to do for {name}: {actions[name]}.")
    elif degraded:
        parts.append(f"No failure diagnosed, but {', '.join(degraded)} "
                     f"{'shows' if len(degraded) == 1 else 'show'} threshold exceedances.")
    else:
        parts.append("No failure diagnosed.")
    return " ".join(p.replace("..", ".") for p in parts)
