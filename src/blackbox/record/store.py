"""The health log on disk: one SQLite file in WAL mode with a versioned schema.

SQLite because it is a single file that survives a SIGKILL or a power cut at any instant
(the write-ahead log is replayed on the next open), needs no server, and answers the range
queries of the external interface from indexes. Rows stay small: entities and
characteristics are interned once in ``channels`` and entries reference them by number,
so a periodic sample costs tens of bytes, which is what makes 4000 hours fit in a budget.
"""

from __future__ import annotations

import contextlib
import json
import math
import sqlite3
import time as _time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

SCHEMA_VERSION = 3
APPLICATION_ID = 0x42424C47
"""``PRAGMA application_id`` of a health log ("BBLG"): how a file is recognised as one."""

#: Entry kinds and their retention priority: lower numbers are thinned and dropped first.
KINDS: dict[str, int] = {
    "sample": 0,
    "observation": 10,
    "exceedance": 11,
    "diagnosis": 12,
    "snapshot": 20,
    "failure": 30,
    "blackbox_event": 31,
    "config": 32,
}
KIND_NAMES: dict[int, str] = {v: k for k, v in KINDS.items()}


class StorageError(Exception):
    """The store cannot be opened or written; the message says what and where."""


class StoreCorrupt(StorageError):
    """The file is not a healthy SQLite database."""


@dataclass(frozen=True, slots=True)
class LogEntry:
    """One uniquely numbered, timestamped record of the health log.

    ``entity`` is the node or topic the entry is about (``None`` for robot-wide entries),
    ``characteristic`` the observer type, ``code`` the observation code where one applies.
    """

    id: int
    time: float
    kind: str
    entity: str | None = None
    characteristic: str | None = None
    code: int | None = None
    payload: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "time": self.time,
            "kind": self.kind,
            "entity": self.entity,
            "characteristic": self.characteristic,
            "code": self.code,
            "payload": self.payload,
        }


Channel = tuple[str | None, str | None, str]
_CHUNK = 200  # rows per INSERT statement (5 parameters each; SQLite allows 32,766)


class Row(NamedTuple):
    """An entry before it has an id: what the recorder hands to :meth:`Store.append`.

    ``channel`` is the identity of the observed characteristic (entity, characteristic,
    resource JSON); rows without one are robot-wide. ``payload`` is a dictionary, or its
    JSON text when the caller encoded it already. Any tuple of these five fields is
    accepted where a row is: the recorder's hot path builds plain tuples.
    """

    time: float
    kind: str
    channel: Channel | None = None
    code: int | None = None
    payload: dict[str, Any] | str = {}  # shared default: rows without a payload never mutate it


RowTuple = tuple[float, str, Channel | None, int | None, dict[str, Any] | str]
"""What :meth:`Store.append` takes: a :class:`Row` or a plain tuple of its five fields."""


def _script(db: sqlite3.Connection, sql: str) -> None:
    # executescript() would commit the migration's transaction half way.
    for statement in sql.split(";"):
        if statement.strip():
            db.execute(statement)


def _v1(db: sqlite3.Connection) -> None:
    _script(
        db,
        """
        CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        CREATE TABLE channels (
            id INTEGER PRIMARY KEY,
            entity TEXT,
            characteristic TEXT,
            resource TEXT NOT NULL,
            UNIQUE (entity, characteristic, resource)
        );
        CREATE TABLE entries (
            id INTEGER PRIMARY KEY AUTOINCREMENT,
            time REAL NOT NULL,
            kind INTEGER NOT NULL,
            channel INTEGER REFERENCES channels(id),
            code INTEGER,
            payload TEXT NOT NULL
        );
        CREATE INDEX entries_time ON entries (time);
        CREATE INDEX entries_channel_time ON entries (channel, time);
        """
    )


def _v2(db: sqlite3.Connection) -> None:
    # Retention looks for the oldest rows of one kind; without this it scans the table.
    db.execute("CREATE INDEX entries_kind_time ON entries (kind, time)")


def _v3(db: sqlite3.Connection) -> None:
    # The files the recorder wrote into its snapshot directory: retention deletes only these.
    db.execute("CREATE TABLE snapshot_files (name TEXT PRIMARY KEY, created REAL NOT NULL)")
    db.execute(f"PRAGMA application_id = {APPLICATION_ID}")


MIGRATIONS: tuple[Callable[[sqlite3.Connection], None], ...] = (_v1, _v2, _v3)


def _loads(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except ValueError:
        return {"unreadable": text}
    return value if isinstance(value, dict) else {"value": value}


def _json_default(value: Any) -> Any:
    if isinstance(value, set | frozenset | tuple):
        return sorted(value) if isinstance(value, set | frozenset) else list(value)
    if hasattr(value, "item"):  # numpy scalars
        return value.item()
    return str(value)


def _reusable(encoder: json.JSONEncoder) -> Callable[[Any], str]:
    """``encoder.encode``, minus building a new C encoder for every call.

    ``JSONEncoder.encode`` makes its C encoder afresh each time, which is a third of
    the cost of a small payload; the writer thread encodes every logged record. Without
    the C accelerator (another Python implementation) the plain method is used.
    """
    make = getattr(json.encoder, "c_make_encoder", None)
    if make is None:
        return encoder.encode
    iterencode = make(None, encoder.default, json.encoder.encode_basestring_ascii, None,
                      encoder.key_separator, encoder.item_separator, encoder.sort_keys,
                      encoder.skipkeys, encoder.allow_nan)

    def encode(value: Any) -> str:
        return "".join(iterencode(value, 0))

    return encode


_ENCODE = _reusable(json.JSONEncoder(separators=(",", ":"), allow_nan=False,
                                     default=_json_default))
_ENCODE_LENIENT = _reusable(json.JSONEncoder(separators=(",", ":"), default=_json_default))


def dumps(value: Any) -> str:
    """Compact JSON; non-finite floats become strings because JSON has no NaN."""
    try:
        return _ENCODE(value)
    except ValueError:
        return _ENCODE_LENIENT(_finite(value))


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


class Store:
    """A health log file. One writer (the recorder) and any number of readers.

    ``durability="full"`` syncs the log to the medium at every commit (survives power
    loss), ``"normal"`` only at checkpoints (survives a crash of the process, not of the
    machine).
    """

    def __init__(self, db: sqlite3.Connection, path: Path, readonly: bool) -> None:
        self._db = db
        self.path = path
        self.readonly = readonly
        self._channels: dict[Channel, int] = {}

    # ---- opening --------------------------------------------------------------------------

    @classmethod
    def open(cls, path: str | Path, *, readonly: bool = False, durability: str = "full",
             check: bool = True) -> Store:
        """Open (and for writing create or migrate) the store at ``path``.

        Raises :class:`StoreCorrupt` when the file is not a healthy database and
        :class:`StorageError` for everything else that prevents opening it.
        """
        p = Path(path)
        if readonly and not p.exists():
            raise StorageError(f"{p}: no such health log")
        try:
            if readonly:
                db = sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True,
                                     check_same_thread=False, isolation_level=None)
            else:
                p.parent.mkdir(parents=True, exist_ok=True)
                db = sqlite3.connect(p, check_same_thread=False, isolation_level=None)
        except (sqlite3.Error, OSError) as exc:
            raise StorageError(f"{p}: cannot open: {exc}") from None
        store = cls(db, p, readonly)
        try:
            store._prepare(durability, check)
        except sqlite3.DatabaseError as exc:
            db.close()
            text = str(exc)
            if isinstance(exc, sqlite3.OperationalError) and "corrupt" not in text \
                    and "malformed" not in text:
                raise StorageError(f"{p}: {text}") from None
            raise StoreCorrupt(f"{p}: not a healthy health log ({text})") from None
        except StorageError:
            db.close()
            raise
        return store

    def _prepare(self, durability: str, check: bool) -> None:
        db = self._db
        db.execute("PRAGMA busy_timeout = 5000")
        version = db.execute("PRAGMA user_version").fetchone()[0]
        if check:
            result = db.execute("PRAGMA quick_check").fetchone()[0]
            if result != "ok":
                raise StoreCorrupt(f"{self.path}: integrity check failed: {result}")
        if version > SCHEMA_VERSION:
            raise StorageError(f"{self.path}: schema version {version} was written by a newer "
                               f"blackbox (this one reads up to {SCHEMA_VERSION})")
        if self.readonly:
            if version == 0:
                raise StorageError(f"{self.path}: not a health log (empty or foreign database)")
            return
        if version == 0:
            tables = db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
            if tables:
                raise StoreCorrupt(f"{self.path}: a database, but not a health log")
            db.execute("PRAGMA auto_vacuum = INCREMENTAL")
        mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if mode.lower() != "wal":
            raise StorageError(f"{self.path}: cannot use write-ahead logging (got {mode})")
        db.execute(f"PRAGMA synchronous = {'FULL' if durability == 'full' else 'NORMAL'}")
        for step in range(version, SCHEMA_VERSION):
            db.execute("BEGIN IMMEDIATE")
            try:
                MIGRATIONS[step](db)
                db.execute(f"PRAGMA user_version = {step + 1}")
                if step == 0:
                    db.execute("INSERT INTO meta VALUES ('created', ?)", (repr(_time.time()),))
                db.execute("COMMIT")
            except BaseException:
                db.execute("ROLLBACK")
                raise

    @property
    def schema_version(self) -> int:
        return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def close(self) -> None:
        try:
            if not self.readonly:
                self._db.execute("PRAGMA wal_checkpoint(PASSIVE)")
        except sqlite3.Error:
            pass
        self._db.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- writing --------------------------------------------------------------------------

    def _add_channels(self, keys: Sequence[Channel]) -> None:
        """Create the channels of ``keys`` that do not exist and learn all ids, in a few
        statements whatever the number (see :meth:`_insert` on why that matters)."""
        db = self._db
        for chunk in _chunks(keys, _CHUNK):
            db.execute("INSERT OR IGNORE INTO channels (entity, characteristic, resource) "
                       "VALUES " + ", ".join(["(?, ?, ?)"] * len(chunk)),
                       [v for key in chunk for v in key])
        table = db.execute("SELECT json_group_array(json_array(id, entity, characteristic, "
                           "resource)) FROM channels").fetchone()[0]
        self._channels = {(e, c, r): cid for cid, e, c, r in json.loads(table)}

    def append(self, rows: Sequence[RowTuple],
               meta: Mapping[str, str] | None = None,
               snapshots: Sequence[tuple[str, float]] = ()) -> list[int]:
        """Write ``rows`` (and ``meta`` keys, and ``(name, created)`` snapshot files for
        the manifest, see :meth:`register_snapshot`) in one transaction; returns the ids.

        All or nothing. Configuration rows whose payload ``version`` is ``None`` get the
        next version number inside the transaction, so concurrent writers never share a
        version.
        """
        db = self._db
        numbered: list[dict[str, Any]] = []
        db.execute("BEGIN IMMEDIATE")
        try:
            ids = self._insert(rows, numbered)
            if meta:
                db.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", meta.items())
            if snapshots:
                db.executemany("INSERT OR IGNORE INTO snapshot_files VALUES (?, ?)", snapshots)
            db.execute("COMMIT")
        except BaseException:
            self._rollback()
            for payload in numbered:
                payload["version"] = None
            raise
        return ids

    def _next_config_version(self) -> int:
        row = self._db.execute(
            "SELECT max(CAST(json_extract(payload, '$.version') AS INTEGER)) FROM entries "
            "WHERE kind = ?", (KINDS["config"],)).fetchone()
        return int(row[0] or 0) + 1

    def _insert(self, rows: Sequence[RowTuple],
                numbered: list[dict[str, Any]] | None = None) -> list[int]:
        if not rows:
            return []
        db = self._db
        channels = self._channels
        kinds = KINDS
        new = {row[2] for row in rows if row[2] is not None and row[2] not in channels}
        if new:
            self._add_channels(sorted(new, key=repr))
            channels = self._channels
        params: list[Any] = []
        version: int | None = None
        for row in rows:
            time, kind, channel, code, payload = row
            if not isinstance(payload, str):
                if kind == "config" and payload.get("version") is None:
                    version = self._next_config_version() if version is None else version + 1
                    payload["version"] = version
                    if numbered is not None:
                        numbered.append(payload)
                payload = dumps(payload)
            params += (time, kinds[kind], None if channel is None else channels[channel], code,
                       payload)
        # Multi-row statements, not executemany: the sqlite3 module releases the GIL for
        # every statement step, and a thread running flat out (the pipeline on a simulated
        # clock) then holds it for a whole switch interval (5 ms) each time: executemany
        # of 1,000 rows took 0.4-2.6 s instead of 20 ms. Now a commit needs a few steps.
        width = 5 * _CHUNK
        for start in range(0, len(params), width):
            part = params[start:start + width]
            db.execute("INSERT INTO entries (time, kind, channel, code, payload) VALUES "
                       + ", ".join(["(?, ?, ?, ?, ?)"] * (len(part) // 5)), part)
        # Inside one write transaction AUTOINCREMENT ids are consecutive.
        last = int(db.execute("SELECT last_insert_rowid()").fetchone()[0])
        return list(range(last - len(rows) + 1, last + 1))

    def _rollback(self) -> None:
        with contextlib.suppress(sqlite3.Error):
            self._db.execute("ROLLBACK")
        # Channel ids inserted in the failed transaction do not exist any more.
        self._channels.clear()

    def update_payload(self, entry_id: int, changes: dict[str, Any]) -> None:
        """Merge ``changes`` into one entry's payload (a failure learns its snapshot file)."""
        row = self._db.execute("SELECT payload FROM entries WHERE id = ?", (entry_id,)).fetchone()
        if row is None:
            return
        payload = _loads(row[0])
        payload.update(changes)
        self._db.execute("UPDATE entries SET payload = ? WHERE id = ?", (dumps(payload), entry_id))

    def delete_where(self, where: str, params: Sequence[Any] = ()) -> int:
        """Delete entries matching an SQL condition (retention and purge only)."""
        cur = self._db.execute(f"DELETE FROM entries WHERE {where}", tuple(params))
        return cur.rowcount

    def execute(self, sql: str, params: Sequence[Any] = ()) -> sqlite3.Cursor:
        return self._db.execute(sql, tuple(params))

    def purge(self, now: float, *, by: str = "operator", keep_config: bool = True) -> LogEntry:
        """Empty the log, keeping the latest configuration version, and record the purge."""
        db = self._db
        db.execute("BEGIN IMMEDIATE")
        try:
            latest = db.execute("SELECT max(id) FROM entries WHERE kind = ?",
                                (KINDS["config"],)).fetchone()[0]
            keep = latest if (keep_config and latest is not None) else -1
            count = db.execute("DELETE FROM entries WHERE id != ?", (keep,)).rowcount
            db.execute("DELETE FROM channels WHERE id NOT IN "
                       "(SELECT channel FROM entries WHERE channel IS NOT NULL)")
            payload = {"event": "purge", "deleted": count, "by": by,
                       "kept_config_entry": latest if keep_config else None}
            (eid,) = self._insert([Row(now, "blackbox_event", None, None, payload)])
            db.execute("COMMIT")
        except BaseException:
            self._rollback()
            raise
        self._channels.clear()
        self.reclaim()
        return LogEntry(eid, now, "blackbox_event", None, None, None, payload)

    def reclaim(self) -> None:
        """Give free pages back to the file system (retention and purge)."""
        try:
            self._db.execute("PRAGMA incremental_vacuum")
            self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        except sqlite3.Error:
            pass

    # ---- size -----------------------------------------------------------------------------

    def used_bytes(self) -> int:
        """Bytes the log occupies on disk, not counting free pages, plus the WAL file."""
        db = self._db
        page = db.execute("PRAGMA page_size").fetchone()[0]
        count = db.execute("PRAGMA page_count").fetchone()[0]
        free = db.execute("PRAGMA freelist_count").fetchone()[0]
        wal = Path(f"{self.path}-wal")
        try:
            wal_size = wal.stat().st_size
        except OSError:
            wal_size = 0
        return int((count - free) * page + wal_size)

    # ---- the snapshot manifest -------------------------------------------------------------

    def register_snapshot(self, name: str, created: float) -> None:
        """Note a snapshot file before it is written: retention may delete only these."""
        self._db.execute("INSERT OR IGNORE INTO snapshot_files VALUES (?, ?)", (name, created))

    def snapshot_files(self) -> list[str]:
        """Names of the snapshot files this log's recorder wrote, oldest first."""
        return [r[0] for r in self._db.execute(
            "SELECT name FROM snapshot_files ORDER BY created, name")]

    def forget_snapshots(self, names: Sequence[str]) -> None:
        self._db.executemany("DELETE FROM snapshot_files WHERE name = ?", [(n,) for n in names])

    def meta(self, key: str) -> str | None:
        row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_meta(self, key: str, value: str) -> None:
        self._db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))

    def count(self, kind: str | None = None) -> int:
        if kind is None:
            return int(self._db.execute("SELECT count(*) FROM entries").fetchone()[0])
        return int(self._db.execute("SELECT count(*) FROM entries WHERE kind = ?",
                                    (KINDS[kind],)).fetchone()[0])

    def integrity_check(self) -> str:
        return str(self._db.execute("PRAGMA integrity_check").fetchone()[0])

    # ---- reading --------------------------------------------------------------------------

    def query(self, entity: str | None = None, characteristic: str | None = None,
              start: float | None = None, end: float | None = None,
              kinds: Sequence[str] | None = None, limit: int | None = None,
              after_id: int | None = None) -> Iterator[LogEntry]:
        """Entries in time order matching every given filter.

        ``entity`` and ``characteristic`` match exactly, or as a glob when they contain
        ``*``, ``?`` or ``[``; ``start`` and ``end`` are inclusive; ``after_id`` continues
        a previous query.
        """
        where: list[str] = []
        params: list[Any] = []
        for column, value in (("c.entity", entity), ("c.characteristic", characteristic)):
            if value is not None:
                op = "GLOB" if any(ch in value for ch in "*?[") else "="
                where.append(f"{column} {op} ?")
                params.append(value)
        if start is not None:
            where.append("e.time >= ?")
            params.append(start)
        if end is not None:
            where.append("e.time <= ?")
            params.append(end)
        if kinds:
            unknown = [k for k in kinds if k not in KINDS]
            if unknown:
                raise ValueError(f"unknown kind {unknown[0]!r}; known: {', '.join(KINDS)}")
            where.append(f"e.kind IN ({','.join('?' * len(kinds))})")
            params.extend(KINDS[k] for k in kinds)
        if after_id is not None:
            where.append("e.id > ?")
            params.append(after_id)
        sql = ("SELECT e.id, e.time, e.kind, c.entity, c.characteristic, e.code, e.payload "
               "FROM entries e LEFT JOIN channels c ON c.id = e.channel")
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY e.time, e.id"
        if limit is not None:
            sql += " LIMIT ?"
            params.append(int(limit))
        cur = self._db.execute(sql, params)
        while True:
            batch = cur.fetchmany(512)
            if not batch:
                return
            for eid, t, kind, ent, ch, code, payload in batch:
                yield LogEntry(eid, t, KIND_NAMES.get(kind, f"kind{kind}"), ent, ch, code,
                               _loads(payload))

    def get(self, entry_id: int) -> LogEntry | None:
        row = self._db.execute(
            "SELECT e.id, e.time, e.kind, c.entity, c.characteristic, e.code, e.payload "
            "FROM entries e LEFT JOIN channels c ON c.id = e.channel WHERE e.id = ?",
            (entry_id,)).fetchone()
        if row is None:
            return None
        eid, t, kind, ent, ch, code, payload = row
        return LogEntry(eid, t, KIND_NAMES.get(kind, f"kind{kind}"), ent, ch, code,
                        _loads(payload))

    def latest(self, kind: str) -> LogEntry | None:
        """The most recently written entry of ``kind``."""
        row = self._db.execute("SELECT max(id) FROM entries WHERE kind = ?",
                               (KINDS[kind],)).fetchone()[0]
        return None if row is None else self.get(int(row))


def _chunks(items: Sequence[Channel], n: int) -> Iterator[Sequence[Channel]]:
    for start in range(0, len(items), n):
        yield items[start:start + n]
