"""The health log on disk: one SQLite file in WAL mode with a versioned schema.

SQLite because it is a single file that survives a SIGKILL or a power cut at any instant
(the write-ahead log is replayed on the next open), needs no server, and answers the range
queries of the external interface from indexes. Entities and characteristics are interned
once in ``channels`` and entries reference them by number.

Two tables hold entries. ``entries`` has one row per entry: diagnoses, failures, events,
configurations, snapshots (rare, and some are updated later), and logged observations that
come few at a time. Logged observations that come in bulk (at least :data:`FRAME_MIN` of one
kind and channel in a commit; under load, hundreds of thousands a second) are stored in
``frames``: one row per commit, kind and channel, holding that group's observations
encoded together (MessagePack, then LZ4). A row of ``entries`` costs SQLite 7-10 us of CPU
with its three indexes; an observation in a frame 0.4-1.1 us, encoding included
(docs/benchmarks.md, "Recorder under load").
Every entry, in either table, has its own id from one sequence, and :meth:`Store.query`
merges both in time order, so readers never see the difference.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import json
import math
import os
import sqlite3
import time as _time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import lz4.frame  # type: ignore[import-untyped]
import msgspec

from blackbox.errors import BlackBoxError
from blackbox.model import Code, Observation

SCHEMA_VERSION = 4
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


class StorageError(BlackBoxError):
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
    JSON text when the caller encoded it already, or a logged :class:`Observation`: such
    a row is stored in a frame, its payload read back as
    :func:`~blackbox.record.policy.observation_payload` of it (``time`` and ``code`` must
    be the observation's). Any tuple of these five fields is accepted where a row is: the
    recorder's hot path builds plain tuples.
    """

    time: float
    kind: str
    channel: Channel | None = None
    code: int | None = None
    payload: dict[str, Any] | str | Observation = {}  # shared default, never mutated


RowTuple = tuple[float, str, Channel | None, int | None, dict[str, Any] | str | Observation]
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


def _v4(db: sqlite3.Connection) -> None:
    # Logged observations in groups (see the module's docstring). first_id/last_id and
    # t_min/t_max bound the entries' ids and times; ``data`` is
    # LZ4(MessagePack([ids, records])); ``thinned`` once retention thinned it.
    _script(
        db,
        """
        CREATE TABLE frames (
            id INTEGER PRIMARY KEY,
            first_id INTEGER NOT NULL,
            last_id INTEGER NOT NULL,
            count INTEGER NOT NULL,
            kind INTEGER NOT NULL,
            channel INTEGER REFERENCES channels(id),
            t_min REAL NOT NULL,
            t_max REAL NOT NULL,
            thinned INTEGER NOT NULL DEFAULT 0,
            data BLOB NOT NULL
        );
        CREATE INDEX frames_time ON frames (t_max);
        CREATE INDEX frames_channel_time ON frames (channel, t_max);
        CREATE INDEX frames_kind_time ON frames (kind, t_max);
        CREATE INDEX frames_first ON frames (first_id)
        """
    )
    # The one id sequence of entries and frames: make sure it exists from the start.
    if db.execute("SELECT count(*) FROM sqlite_sequence WHERE name = 'entries'").fetchone()[0] \
            == 0:
        db.execute("INSERT INTO sqlite_sequence (name, seq) "
                   "SELECT 'entries', coalesce(max(id), 0) FROM entries")


MIGRATIONS: tuple[Callable[[sqlite3.Connection], None], ...] = (_v1, _v2, _v3, _v4)


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


def _frame_hook(value: Any) -> Any:
    if hasattr(value, "item") and not isinstance(value, Mapping):  # numpy scalars
        return value.item()
    if isinstance(value, Mapping):
        return dict(value)
    raise TypeError(f"cannot store a {type(value).__name__} in a frame")


_FRAME_ENCODER = msgspec.msgpack.Encoder(enc_hook=_frame_hook)
_FRAME_DECODER = msgspec.msgpack.Decoder()
FRAME_MIN = 8
"""Fewer observations of one kind and channel in a commit are stored as rows of
``entries``: a frame of one or two costs more bytes than their JSON."""
THINNED = 4
"""Retention keeps one sample in this many (the ``thinned`` mark of the survivors)."""


def encode_frame(ids: Sequence[int], observations: Sequence[Observation]) -> bytes:
    """A frame's ``data``: LZ4 of the MessagePack of the columns ``[ids, times, codes,
    states, values, messages]`` (kind, entity, characteristic and resource are the frame's
    channel). Columns, because building them allocates no object per observation.
    Raises :class:`TypeError` when an observation holds a value that MessagePack cannot
    carry (the caller stores those rows one by one, as JSON)."""
    return _pack((ids, [o.time for o in observations], [o.code for o in observations],
                  [o.states for o in observations], [o.values for o in observations],
                  [o.message for o in observations]))


def _pack(columns: Sequence[Sequence[Any]]) -> bytes:
    return bytes(lz4.frame.compress(_FRAME_ENCODER.encode(columns)))


def decode_frame(data: bytes) -> tuple[list[int], list[tuple[Any, ...]]]:
    """The entry ids and records ``(time, code, states, values, message)`` of a frame."""
    ids, *columns = _FRAME_DECODER.decode(lz4.frame.decompress(data))
    return ids, list(zip(*columns, strict=True))


def _observation_json(obs: Observation, kind: str) -> str:
    """A logged observation as an ``entries`` payload; never raises, so no row can block
    the log."""
    from blackbox.record.policy import observation_payload

    try:
        return dumps(observation_payload(obs, kind != "sample"))
    except (TypeError, ValueError, RecursionError) as exc:
        return dumps({"code_name": obs.code.name, "message": obs.message,
                      "unencodable": f"{type(exc).__name__}: {exc}"})


def _code_name(code: Any) -> str:
    try:
        return Code(code).name
    except ValueError:
        return str(code)


def frame_payload(record: Sequence[Any], full: bool) -> dict[str, Any]:
    """What :func:`~blackbox.record.policy.observation_payload` made of the observation,
    as the JSON of an ``entries`` row reads back (non-finite numbers as text)."""
    _, code, states, values, message = record
    payload: dict[str, Any] = {"values": values, "states": [s["number"] for s in states]}
    if full:
        payload["state_names"] = [s["name"] for s in states]
        payload["code_name"] = _code_name(code)
        if message:
            payload["message"] = message
    values = payload["values"]
    if not all(type(v) is not float or math.isfinite(v) for v in values.values()):
        payload["values"] = _finite(values)
    return payload


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
            self._create()
            version = SCHEMA_VERSION
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

    def _create(self) -> None:
        """Create the whole schema in one transaction in rollback-journal mode.

        In WAL mode a new log's header (application id, schema version) and tables would
        sit in the WAL until the first checkpoint (about 4 MB of commits, minutes of a
        real-time run), and a crash before it left a main file that does not say it is a
        health log. Created with a rollback journal, the commit writes them into the main
        file itself and syncs it before the journal goes; only then does the caller switch
        to WAL (which rewrites two header bytes, also synced). A crash during creation
        leaves an empty file or a hot journal that the next open rolls back to an empty
        file, never a half-made log. Chosen over a checkpoint right after creation because
        that leaves a window (commit in the WAL, checkpoint not yet done) and this does not.
        """
        db = self._db
        if db.execute("PRAGMA journal_mode = DELETE").fetchone()[0].lower() != "delete":
            raise StorageError(f"{self.path}: cannot create the log with a rollback journal")
        db.execute("PRAGMA synchronous = FULL")
        # A deferred BEGIN, then auto_vacuum: so the setting goes into the same (first)
        # commit. Outside a transaction it commits an empty page 1 of its own, a moment in
        # which the file would be a database without the application id.
        db.execute("BEGIN")
        try:
            db.execute("PRAGMA auto_vacuum = INCREMENTAL")
            for migrate in MIGRATIONS:
                migrate(db)
            db.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            db.execute("INSERT INTO meta VALUES ('created', ?)", (repr(_time.time()),))
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        _sync_directory(self.path.parent)

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
               snapshots: Sequence[tuple[str, float]] = (), *,
               want_ids: bool = True) -> list[int]:
        """Write ``rows`` (and ``meta`` keys, and ``(name, created)`` snapshot files for
        the manifest, see :meth:`register_snapshot`) in one transaction; returns the ids
        in the order of ``rows`` (an empty list with ``want_ids=False``).

        All or nothing. Configuration rows whose payload ``version`` is ``None`` get the
        next version number inside the transaction, so concurrent writers never share a
        version. Rows whose payload is an :class:`Observation` go into frames.
        """
        db = self._db
        numbered: list[dict[str, Any]] = []
        db.execute("BEGIN IMMEDIATE")
        try:
            ids = self._insert(rows, numbered, want_ids)
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
                numbered: list[dict[str, Any]] | None = None,
                want_ids: bool = True) -> list[int]:
        """Insert ``rows`` with ids in their order, from the one sequence of both tables;
        logged observations grouped into frames by kind and channel."""
        if not rows:
            return []
        db = self._db
        seq = db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'entries'").fetchone()
        if seq is None:
            db.execute("INSERT INTO sqlite_sequence (name, seq) VALUES ('entries', 0)")
        base = int(seq[0]) + 1 if seq is not None else 1
        plain: list[tuple[int, RowTuple]] = []
        # Grouped by the channel tuple's identity first (all rows are alive meanwhile, so
        # ids are unique): the policy hands one tuple per characteristic, and hashing its
        # text for every row costs more. Then equal tuples are merged, group by group.
        groups: dict[tuple[str, int],
                     tuple[Channel | None, list[int], list[Observation]]] = {}
        for eid, row in enumerate(rows, base):
            payload = row[4]
            if type(payload) is Observation:
                key = (row[1], id(row[2]))
                group = groups.get(key)
                if group is None:
                    groups[key] = (row[2], [eid], [payload])
                else:
                    group[1].append(eid)
                    group[2].append(payload)
            else:
                plain.append((eid, row))
        frames: list[tuple[str, Channel | None, list[int], list[Observation], bytes]] = []
        for (kind, channel), (ids, members) in _merge_equal(groups).items():
            try:
                if len(members) < FRAME_MIN:
                    raise TypeError("too few for a frame")
                frames.append((kind, channel, ids, members, encode_frame(ids, members)))
            except (TypeError, ValueError, OverflowError):
                plain += [(eid, (o.time, kind, channel, int(o.code), _observation_json(o, kind)))
                          for eid, o in zip(ids, members, strict=True)]
        channels = self._channels
        new = {r[2] for _, r in plain if r[2] is not None and r[2] not in channels}
        new.update(f[1] for f in frames if f[1] is not None and f[1] not in channels)
        if new:
            self._add_channels(sorted(new, key=repr))
        self._insert_entries(plain, numbered)
        self._insert_frames(frames)
        last = base + len(rows) - 1
        db.execute("UPDATE sqlite_sequence SET seq = ? WHERE name = 'entries'", (last,))
        return list(range(base, last + 1)) if want_ids else []

    def _insert_entries(self, rows: Sequence[tuple[int, RowTuple]],
                        numbered: list[dict[str, Any]] | None) -> None:
        if not rows:
            return
        db = self._db
        channels = self._channels
        kinds = KINDS
        params: list[Any] = []
        version: int | None = None
        for eid, (time, kind, channel, code, payload) in rows:
            if not isinstance(payload, str):
                if isinstance(payload, Observation):
                    payload = _observation_json(payload, kind)
                else:
                    if kind == "config" and payload.get("version") is None:
                        version = self._next_config_version() if version is None \
                            else version + 1
                        payload["version"] = version
                        if numbered is not None:
                            numbered.append(payload)
                    payload = dumps(payload)
            params += (eid, time, kinds[kind], None if channel is None else channels[channel],
                       code, payload)
        # Multi-row statements, not executemany: the sqlite3 module releases the GIL for
        # every statement step, and a thread running flat out (the pipeline on a simulated
        # clock) then holds it for a whole switch interval (5 ms) each time: executemany
        # of 1,000 rows took 0.4-2.6 s instead of 20 ms. Now a commit needs a few steps.
        width = 6 * _CHUNK
        for start in range(0, len(params), width):
            part = params[start:start + width]
            db.execute("INSERT INTO entries (id, time, kind, channel, code, payload) VALUES "
                       + ", ".join(["(?, ?, ?, ?, ?, ?)"] * (len(part) // 6)), part)

    def _insert_frames(self, frames: Sequence[tuple[str, Channel | None, list[int],
                                                    list[Observation], bytes]]) -> None:
        if not frames:
            return
        channels = self._channels
        params: list[tuple[Any, ...]] = []
        for kind, channel, ids, group, data in frames:
            times = [o.time for o in group]
            params.append((ids[0], ids[-1], len(ids), KINDS[kind],
                           None if channel is None else channels[channel],
                           min(times), max(times), data))
        self._db.executemany("INSERT INTO frames (first_id, last_id, count, kind, channel, "
                             "t_min, t_max, data) VALUES (?, ?, ?, ?, ?, ?, ?, ?)", params)

    def _rollback(self) -> None:
        with contextlib.suppress(sqlite3.Error):
            self._db.execute("ROLLBACK")
        # Channel ids inserted in the failed transaction do not exist any more.
        self._channels.clear()

    def thin_frames(self, kind: int, before: float) -> int:
        """Keep one in :data:`THINNED` of the not yet thinned observations of ``kind`` in
        frames that end before ``before``, counted per channel in time order (retention,
        inside its transaction). Returns how many were removed."""
        db = self._db
        frames = db.execute(
            "SELECT id, channel, data FROM frames WHERE kind = ? AND thinned = 0 "
            "AND t_max < ? ORDER BY channel, t_min, first_id", (kind, before)).fetchall()
        seen: dict[int | None, int] = {}
        removed = 0
        for fid, channel, data in frames:
            ids, observations = decode_frame(data)
            n = seen.get(channel, 0)
            kept = [(eid, o) for i, (eid, o) in enumerate(zip(ids, observations, strict=True))
                    if (n + i) % THINNED == 0]
            seen[channel] = n + len(observations)
            removed += len(observations) - len(kept)
            if not kept:
                db.execute("DELETE FROM frames WHERE id = ?", (fid,))
                continue
            kept_ids = [eid for eid, _ in kept]
            times = [float(r[0]) for _, r in kept]
            db.execute("UPDATE frames SET first_id = ?, last_id = ?, count = ?, t_min = ?, "
                       "t_max = ?, thinned = 1, data = ? WHERE id = ?",
                       (min(kept_ids), max(kept_ids), len(kept), min(times), max(times),
                        _pack((kept_ids, *map(list, zip(*(r for _, r in kept), strict=True)))),
                        fid))
        return removed

    def thin_samples(self, kind: int) -> int:
        """Thin the older half of the not yet thinned entries of ``kind`` (periodic samples)
        to one in four per channel, in one transaction (retention). Returns how many went."""
        count, t0, t1 = self._db.execute(
            "SELECT count(*), min(time), max(time) FROM entries "
            "WHERE kind = ? AND json_extract(payload, '$.thinned') IS NULL", (kind,)
        ).fetchone()
        framed, f0, f1 = self._db.execute(
            "SELECT coalesce(sum(count), 0), min(t_min), max(t_max) FROM frames "
            "WHERE kind = ? AND thinned = 0", (kind,)).fetchone()
        count += framed
        if count < 8:
            return 0
        t0 = min(t for t in (t0, f0) if t is not None)
        t1 = max(t for t in (t1, f1) if t is not None)
        cut = t0 + (t1 - t0) / 2
        self._db.execute("BEGIN IMMEDIATE")
        try:
            removed = self.delete_where(
                "id IN (SELECT id FROM (SELECT id, row_number() OVER "
                "(PARTITION BY channel ORDER BY time) AS n FROM entries "
                "WHERE kind = ? AND time < ? AND json_extract(payload, '$.thinned') IS NULL) "
                "WHERE n % 4 != 1)", (kind, cut))
            self._db.execute(
                "UPDATE entries SET payload = json_set(payload, '$.thinned', 4) "
                "WHERE kind = ? AND time < ? AND json_extract(payload, '$.thinned') IS NULL",
                (kind, cut))
            removed += self.thin_frames(kind, cut)
            self._db.execute("COMMIT")
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        return removed

    def drop_least_valuable(self, kinds_by_value: Sequence[Sequence[int]]) -> int:
        """Delete the oldest tenth of the first group of kinds (least valuable first) that
        still has entries, never the latest configuration, in one transaction (retention).
        Returns how many went."""
        latest_config = self._db.execute("SELECT max(id) FROM entries WHERE kind = ?",
                                         (KINDS["config"],)).fetchone()[0]
        for kinds in kinds_by_value:
            marks = ",".join("?" * len(kinds))
            n = self._db.execute(f"SELECT count(*) FROM entries WHERE kind IN ({marks}) "
                                 "AND id IS NOT ?", (*kinds, latest_config)).fetchone()[0]
            n += self._db.execute(f"SELECT coalesce(sum(count), 0) FROM frames "
                                  f"WHERE kind IN ({marks})", tuple(kinds)).fetchone()[0]
            if not n:
                continue
            self._db.execute("BEGIN IMMEDIATE")
            try:
                removed = self.drop_oldest(kinds, max(1, n // 10), latest_config)
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            return removed
        return 0

    def checkpoint(self) -> None:
        """Move the write-ahead log into the file (before measuring its size)."""
        self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")

    def drop_oldest(self, kinds: Sequence[int], take: int, keep_id: int | None) -> int:
        """Delete about the ``take`` oldest entries of ``kinds`` (whole frames at a time),
        never ``keep_id`` (retention, inside its transaction). Returns how many."""
        db = self._db
        marks = ",".join("?" * len(kinds))
        times = [t for (t,) in db.execute(
            f"SELECT time FROM entries WHERE kind IN ({marks}) AND id IS NOT ? "
            "ORDER BY time, id LIMIT ?", (*kinds, keep_id, take))]
        frames = db.execute(f"SELECT id, t_min, count FROM frames WHERE kind IN ({marks}) "
                            "ORDER BY t_min, first_id", kinds)
        doomed: list[int] = []
        taken = i = 0  # i: how many of the oldest entries go
        for fid, t_min, count in frames:
            while i < len(times) and taken < take and times[i] <= t_min:
                taken += 1
                i += 1
            if taken >= take:
                break
            doomed.append(fid)
            taken += count
        frames.close()
        i = min(len(times), i + max(0, take - taken))
        removed = 0
        if i:
            removed += db.execute(
                f"DELETE FROM entries WHERE id IN (SELECT id FROM entries WHERE kind IN "
                f"({marks}) AND id IS NOT ? ORDER BY time, id LIMIT ?)",
                (*kinds, keep_id, i)).rowcount
        for fid in doomed:
            removed += int(db.execute("SELECT count FROM frames WHERE id = ?",
                                      (fid,)).fetchone()[0])
            db.execute("DELETE FROM frames WHERE id = ?", (fid,))
        return removed

    def update_payload(self, entry_id: int, changes: dict[str, Any]) -> None:
        """Merge ``changes`` into the payload of one row of ``entries`` (a failure learns its
        snapshot file); entries in frames (logged observations) are not updated."""
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
            count += int(db.execute("SELECT coalesce(sum(count), 0) FROM frames").fetchone()[0])
            db.execute("DELETE FROM frames")
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
        """Entries in the log (of ``kind``), in both tables."""
        if kind is None:
            return int(self._db.execute(
                "SELECT (SELECT count(*) FROM entries) + "
                "(SELECT coalesce(sum(count), 0) FROM frames)").fetchone()[0])
        return int(self._db.execute(
            "SELECT (SELECT count(*) FROM entries WHERE kind = ?1) + "
            "(SELECT coalesce(sum(count), 0) FROM frames WHERE kind = ?1)",
            (KINDS[kind],)).fetchone()[0])

    def integrity_check(self) -> str:
        return str(self._db.execute("PRAGMA integrity_check").fetchone()[0])

    # ---- reading --------------------------------------------------------------------------

    def query(self, entity: str | None = None, characteristic: str | None = None,
              start: float | None = None, end: float | None = None,
              kinds: Sequence[str] | None = None, limit: int | None = None,
              after_id: int | None = None) -> Iterator[LogEntry]:
        """Entries in time order (then id) matching every given filter.

        ``entity`` and ``characteristic`` match exactly, or as a glob when they contain
        ``*``, ``?`` or ``[``; ``start`` and ``end`` are inclusive; ``after_id`` continues
        a previous query. Rows of ``entries`` and observations in frames are merged: a
        frame is decoded only once the merge reaches its first time.
        """
        where: list[str] = []
        params: list[Any] = []
        for column, value in (("c.entity", entity), ("c.characteristic", characteristic)):
            if value is not None:
                op = "GLOB" if any(ch in value for ch in "*?[") else "="
                where.append(f"{column} {op} ?")
                params.append(value)
        if kinds:
            unknown = [k for k in kinds if k not in KINDS]
            if unknown:
                raise ValueError(f"unknown kind {unknown[0]!r}; known: {', '.join(KINDS)}")
            where.append(f"kind IN ({','.join('?' * len(kinds))})")
            params.extend(KINDS[k] for k in kinds)
        entry_where, entry_params = list(where), list(params)
        if start is not None:
            entry_where.append("e.time >= ?")
            entry_params.append(start)
            where.append("f.t_max >= ?")
            params.append(start)
        if end is not None:
            entry_where.append("e.time <= ?")
            entry_params.append(end)
            where.append("f.t_min <= ?")
            params.append(end)
        if after_id is not None:
            entry_where.append("e.id > ?")
            entry_params.append(after_id)
            where.append("f.last_id > ?")
            params.append(after_id)
        sql = ("SELECT e.id, e.time, e.kind, c.entity, c.characteristic, e.code, e.payload "
               "FROM entries e LEFT JOIN channels c ON c.id = e.channel")
        if entry_where:
            sql += " WHERE " + " AND ".join(entry_where)
        sql += " ORDER BY e.time, e.id"
        if limit is not None:
            sql += " LIMIT ?"
            entry_params.append(int(limit))
        rows = self._entry_rows(self._db.execute(sql, entry_params))
        frame_sql = ("SELECT f.kind, c.entity, c.characteristic, f.t_min, f.thinned, f.data "
                     "FROM frames f LEFT JOIN channels c ON c.id = f.channel")
        if where:
            frame_sql += " WHERE " + " AND ".join(where)
        frame_sql += " ORDER BY f.t_min, f.id"
        frames = self._db.execute(frame_sql, params)
        yield from itertools.islice(_merge(rows, frames, start, end, after_id), limit)

    @staticmethod
    def _entry_rows(cur: sqlite3.Cursor) -> Iterator[LogEntry]:
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
            frames = self._db.execute(
                "SELECT f.kind, c.entity, c.characteristic, f.t_min, f.thinned, f.data "
                "FROM frames f LEFT JOIN channels c ON c.id = f.channel "
                "WHERE f.first_id <= ?1 AND f.last_id >= ?1 ORDER BY f.first_id DESC",
                (entry_id,))
            for frame in frames:  # the frames of one commit share a range of ids
                found = next((e for e in frame_entries(frame) if e.id == entry_id), None)
                if found is not None:
                    frames.close()
                    return found
            return None
        eid, t, kind, ent, ch, code, payload = row
        return LogEntry(eid, t, KIND_NAMES.get(kind, f"kind{kind}"), ent, ch, code,
                        _loads(payload))

    def latest(self, kind: str) -> LogEntry | None:
        """The most recently written entry of ``kind``."""
        row = self._db.execute(
            "SELECT max(coalesce((SELECT max(id) FROM entries WHERE kind = ?1), 0), "
            "coalesce((SELECT max(last_id) FROM frames WHERE kind = ?1), 0))",
            (KINDS[kind],)).fetchone()[0]
        return None if not row else self.get(int(row))


def _sync_directory(directory: Path) -> None:
    """Make a new file's name durable: a power cut must not lose the log's directory entry."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


FrameRow = tuple[int, str | None, str | None, float, int, bytes]
"""``kind, entity, characteristic, t_min, thinned, data`` of a frame."""


def frame_entries(frame: FrameRow) -> list[LogEntry]:
    """The entries of one frame, in the order they were written."""
    kind, entity, characteristic, _, thinned, data = frame
    ids, observations = decode_frame(data)
    name = KIND_NAMES.get(kind, f"kind{kind}")
    full = name != "sample"
    entries = [LogEntry(eid, float(r[0]), name, entity, characteristic, r[1],
                        frame_payload(r, full))
               for eid, r in zip(ids, observations, strict=True)]
    if thinned:  # like a thinned row of ``entries``
        for e in entries:
            e.payload["thinned"] = THINNED
    return entries


def _merge_equal(groups: Mapping[tuple[str, int],
                                  tuple[Channel | None, list[int], list[Observation]]]
                 ) -> dict[tuple[str, Channel | None], tuple[list[int], list[Observation]]]:
    """Groups by (kind, channel identity) merged into groups by (kind, channel value),
    members in id order."""
    merged: dict[tuple[str, Channel | None], tuple[list[int], list[Observation]]] = {}
    mixed: set[tuple[str, Channel | None]] = set()
    for (kind, _), (channel, ids, members) in groups.items():
        key = (kind, channel)
        have = merged.get(key)
        if have is None:
            merged[key] = (ids, members)
        else:
            have[0].extend(ids)
            have[1].extend(members)
            mixed.add(key)
    for key in mixed:
        pairs = sorted(zip(*merged[key], strict=True), key=lambda p: p[0])
        merged[key] = ([i for i, _ in pairs], [o for _, o in pairs])
    return merged


def _merge(rows: Iterator[LogEntry], frames: Iterable[FrameRow], start: float | None,
           end: float | None, after_id: int | None) -> Iterator[LogEntry]:
    """``rows`` (in time order) and the frames' entries (frames in order of first time),
    merged by (time, id); each frame is decoded when the merge reaches its first time."""
    heap: list[tuple[float, int, LogEntry]] = []
    pending = iter(frames)
    upcoming = next(pending, None)
    head = next(rows, None)
    while True:
        bound = min(head.time if head is not None else math.inf,
                    heap[0][0] if heap else math.inf)
        while upcoming is not None and (upcoming[3] <= bound or (head is None and not heap)):
            for e in frame_entries(upcoming):
                if (start is None or e.time >= start) and (end is None or e.time <= end) \
                        and (after_id is None or e.id > after_id):
                    heapq.heappush(heap, (e.time, e.id, e))
            upcoming = next(pending, None)
            bound = min(bound, heap[0][0] if heap else math.inf)
        if head is None and not heap:
            return
        if head is not None and (not heap or (head.time, head.id) <= heap[0][:2]):
            yield head
            head = next(rows, None)
        else:
            yield heapq.heappop(heap)[2]


def _chunks(items: Sequence[Channel], n: int) -> Iterator[Sequence[Channel]]:
    for start in range(0, len(items), n):
        yield items[start:start + n]
