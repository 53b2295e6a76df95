"""The alert tables in the station's SQLite file, behind one connection and one lock.

Alerts, the outbox, page-made rules and the counters of unmatched events must survive a
station restart (an alert raised at 02:59 must still be delivered and escalated after a
03:00 restart), so they live next to the fleet data under their own ``alert_`` names,
as the accounts live under ``web_``. Open the station store on the file first: it refuses
a file that already has tables but not its own.
"""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

SCHEMA = """
CREATE TABLE IF NOT EXISTS alert_meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS alert_rules (
    name TEXT PRIMARY KEY,
    text TEXT NOT NULL,
    created REAL NOT NULL,
    created_by TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS alert_alerts (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    rule TEXT NOT NULL,
    key TEXT NOT NULL,
    robot TEXT NOT NULL,
    entity TEXT NOT NULL,
    kind TEXT NOT NULL,
    status TEXT NOT NULL,
    text TEXT NOT NULL,
    event_id INTEGER,
    first REAL NOT NULL,
    last REAL NOT NULL,
    count INTEGER NOT NULL,
    state TEXT NOT NULL,
    fired_at REAL,
    level INTEGER NOT NULL DEFAULT 0,
    acked_by TEXT,
    acked_at REAL,
    resolved_at REAL,
    notified INTEGER NOT NULL DEFAULT 1
);
CREATE INDEX IF NOT EXISTS alert_alerts_key ON alert_alerts (key, state);
CREATE INDEX IF NOT EXISTS alert_alerts_state ON alert_alerts (state, id);
CREATE TABLE IF NOT EXISTS alert_outbox (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    alert_id INTEGER,
    rule TEXT NOT NULL,
    channel TEXT NOT NULL,
    purpose TEXT NOT NULL,
    payload TEXT NOT NULL,
    created REAL NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0,
    next_attempt REAL NOT NULL,
    state TEXT NOT NULL DEFAULT 'pending',
    last_error TEXT NOT NULL DEFAULT '',
    finished REAL
);
CREATE INDEX IF NOT EXISTS alert_outbox_due ON alert_outbox (state, next_attempt);
CREATE TABLE IF NOT EXISTS alert_unmatched (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time REAL NOT NULL,
    kind TEXT NOT NULL,
    robot TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS alert_unmatched_time ON alert_unmatched (time);
CREATE TABLE IF NOT EXISTS alert_rate (
    rule TEXT PRIMARY KEY,
    window_start REAL NOT NULL,
    sent INTEGER NOT NULL,
    suppressed INTEGER NOT NULL,
    examples TEXT NOT NULL DEFAULT '[]'
)
"""


class AlertDB:
    """One write connection to the alert tables, shared by the engine and the outbox."""

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        self.lock = threading.RLock()
        self._depth = 0
        self._db = sqlite3.connect(self.path, check_same_thread=False, timeout=10.0,
                                   isolation_level=None)
        if self.path != ":memory:":
            self._db.execute("PRAGMA journal_mode=WAL")
        with self.lock:
            for statement in SCHEMA.split(";"):
                if statement.strip():
                    self._db.execute(statement)

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """The connection inside ``BEGIN IMMEDIATE`` ... ``COMMIT`` (rolled back on error);
        nested calls join the outer transaction."""
        with self.lock:
            if self._depth:
                self._depth += 1
                try:
                    yield self._db
                finally:
                    self._depth -= 1
                return
            self._db.execute("BEGIN IMMEDIATE")
            self._depth = 1
            try:
                yield self._db
            except BaseException:
                self._depth = 0
                self._db.execute("ROLLBACK")
                raise
            self._depth = 0
            self._db.execute("COMMIT")

    @contextmanager
    def reading(self) -> Iterator[sqlite3.Connection]:
        with self.lock:
            yield self._db

    def meta(self, key: str) -> str | None:
        with self.reading() as db:
            row = db.execute("SELECT value FROM alert_meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_meta(self, db: sqlite3.Connection, key: str, value: str) -> None:
        db.execute("INSERT OR REPLACE INTO alert_meta VALUES (?, ?)", (key, value))

    def size_bytes(self) -> int:
        """Bytes of the whole station database file (pages in use)."""
        with self.reading() as db:
            pages = db.execute("PRAGMA page_count").fetchone()[0]
            size = db.execute("PRAGMA page_size").fetchone()[0]
        return int(pages) * int(size)

    def close(self) -> None:
        with self.lock:
            self._db.close()
