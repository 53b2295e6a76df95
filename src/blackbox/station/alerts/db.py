"""The alert tables in the station's database, behind one connection and one lock.

Alerts, the outbox, page-made rules and the counters of unmatched events must survive a
station restart (an alert raised at 02:59 must still be delivered and escalated after a
03:00 restart), so they live next to the fleet data under their own ``alert_`` names,
as the accounts live under ``web_`` (part of the one versioned schema,
:mod:`blackbox.station.schema`). Open the station store on the database first: it refuses a
file that already has tables but not its own.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from blackbox.station import schema
from blackbox.station.database import (
    Connection,
    Database,
    ReconnectingConnection,
    open_database,
)


class AlertDB:
    """One write connection to the alert tables, shared by the engine and the outbox."""

    def __init__(self, path: str | Path | Database) -> None:
        self.database = open_database(path)
        self.path = self.database.describe()
        self.lock = threading.RLock()
        self._depth = 0
        self._db = ReconnectingConnection(self.database)
        with self.lock:
            if self.database.dialect == "sqlite" and not self.database.memory:
                self._db.execute("PRAGMA journal_mode=WAL")
            schema.ensure_part(self.database, self._db, "alerts")

    @contextmanager
    def transaction(self) -> Iterator[Connection]:
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
            self._db.begin()
            self._depth = 1
            try:
                yield self._db
            except BaseException:
                self._depth = 0
                self._db.rollback()
                raise
            self._depth = 0
            self._db.commit()

    @contextmanager
    def reading(self) -> Iterator[Connection]:
        with self.lock:
            yield self._db

    def meta(self, key: str) -> str | None:
        with self.reading() as db:
            row = db.execute("SELECT value FROM alert_meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_meta(self, db: Connection, key: str, value: str) -> None:
        db.execute("INSERT INTO alert_meta VALUES (?, ?) ON CONFLICT (key) DO UPDATE SET "
                   "value = excluded.value", (key, value))

    def size_bytes(self) -> int:
        """Bytes of the whole station database (the file's pages, or PostgreSQL's size)."""
        with self.reading() as db:
            return self.database.size_bytes(db)

    def close(self) -> None:
        with self.lock:
            self._db.close()
