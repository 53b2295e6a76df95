"""One way to speak SQL to the station's database, whichever engine keeps it.

The station keeps its fleet data, accounts, API tokens, trusted robot keys and alerts in one
database: an SQLite file by default (one process, no server to run), or a PostgreSQL server
(``postgresql://...``) so that several station processes on several machines can share it.
Every module that stores something writes its SQL once, in the subset both engines accept:

* ``?`` placeholders (translated to ``%s`` for psycopg; ``%`` in SQL is escaped for it);
* ``INSERT ... ON CONFLICT (...) DO NOTHING | DO UPDATE`` instead of SQLite's ``OR IGNORE`` /
  ``OR REPLACE``; :meth:`Connection.insert` (``RETURNING id``) instead of ``lastrowid``;
* ``greatest(a, b)`` (a function registered on SQLite connections), ``"user"`` quoted.

Engine failures (disk full, server gone, constraint refused) surface as :class:`DatabaseError`
(:class:`DuplicateRow` for a unique constraint), so callers need not know the driver.
"""

from __future__ import annotations

import contextlib
import functools
import re
import sqlite3
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from blackbox.errors import BlackBoxError

POSTGRES_SCHEMES = ("postgresql://", "postgres://")


class StationStoreError(BlackBoxError):
    """The station database cannot be opened or used; the message says what and where."""


class DatabaseError(StationStoreError):
    """The database engine refused or failed a statement (the message says why): a station
    store error, so the web pages answer 503 and the command line one line."""


class DuplicateRow(DatabaseError):
    """A unique constraint refused a row."""


class Cursor(Protocol):
    """What callers read from a statement: rows and how many rows it changed."""

    @property
    def rowcount(self) -> int: ...

    def fetchone(self) -> Any: ...

    def fetchall(self) -> list[Any]: ...

    def __iter__(self) -> Iterator[Any]: ...


class Connection(Protocol):
    """One connection to the station database (not shared between threads without a lock).

    Autocommit unless :meth:`begin` opened a transaction, ended by :meth:`commit` or
    :meth:`rollback`."""

    def execute(self, sql: str, args: Sequence[Any] = ()) -> Cursor: ...

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None: ...

    def insert(self, sql: str, args: Sequence[Any] = ()) -> int:
        """Run an ``INSERT`` into a table with an ``id`` key and return the new id."""
        ...

    def begin(self) -> None: ...

    def commit(self) -> None: ...

    def rollback(self) -> None: ...

    def close(self) -> None: ...


class Database(Protocol):
    """Where the station's data lives: how to connect and what the engine calls things."""

    @property
    def url(self) -> str: ...

    @property
    def dialect(self) -> str:
        """``sqlite`` or ``postgresql``: which DDL :mod:`blackbox.station.schema` writes."""
        ...

    @property
    def memory(self) -> bool:
        """An SQLite ``:memory:`` database: one connection only, gone with the process."""
        ...

    def connect(self, *, read_only: bool = False) -> Connection: ...

    def table_names(self, db: Connection) -> set[str]: ...

    def size_bytes(self, db: Connection) -> int: ...

    def describe(self) -> str:
        """The location without a password, for messages and logs."""
        ...


# ---- SQLite -----------------------------------------------------------------------------------


class _SqliteConnection:
    def __init__(self, raw: sqlite3.Connection, immediate: bool) -> None:
        self.raw = raw
        self._begin = "BEGIN IMMEDIATE" if immediate else "BEGIN"

    def execute(self, sql: str, args: Sequence[Any] = ()) -> Cursor:
        try:
            return self.raw.execute(sql, args)
        except sqlite3.IntegrityError as exc:
            raise DuplicateRow(str(exc)) from None
        except sqlite3.Error as exc:
            raise DatabaseError(str(exc)) from None

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        try:
            self.raw.executemany(sql, rows)
        except sqlite3.IntegrityError as exc:
            raise DuplicateRow(str(exc)) from None
        except sqlite3.Error as exc:
            raise DatabaseError(str(exc)) from None

    def insert(self, sql: str, args: Sequence[Any] = ()) -> int:
        row = self.execute(sql + " RETURNING id", args).fetchone()
        return int(row[0])

    def begin(self) -> None:
        self.execute(self._begin)

    def commit(self) -> None:
        self.execute("COMMIT")

    def rollback(self) -> None:
        if self.raw.in_transaction:
            self.execute("ROLLBACK")

    def close(self) -> None:
        self.raw.close()


@dataclass(slots=True)
class SqliteDatabase:
    """An SQLite file (WAL) or ``:memory:``."""

    path: str
    dialect: str = "sqlite"

    @property
    def url(self) -> str:
        return self.path

    @property
    def memory(self) -> bool:
        return self.path == ":memory:"

    def connect(self, *, read_only: bool = False) -> Connection:
        try:
            if read_only and not self.memory:
                raw = sqlite3.connect(f"file:{Path(self.path).resolve()}?mode=ro", uri=True,
                                      timeout=10.0, check_same_thread=False)
            else:
                raw = sqlite3.connect(self.path, timeout=10.0, check_same_thread=False,
                                      isolation_level=None)
                raw.execute("PRAGMA foreign_keys=ON")
        except sqlite3.Error as exc:
            raise DatabaseError(f"{self.path}: cannot open: {exc}") from None
        raw.create_function("greatest", -1, _greatest, deterministic=True)
        return _SqliteConnection(raw, immediate=True)

    def table_names(self, db: Connection) -> set[str]:
        return {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}

    def size_bytes(self, db: Connection) -> int:
        pages = db.execute("PRAGMA page_count").fetchone()[0]
        size = db.execute("PRAGMA page_size").fetchone()[0]
        return int(pages) * int(size)

    def describe(self) -> str:
        return self.path


def _greatest(*values: Any) -> Any:
    present = [v for v in values if v is not None]
    return max(present) if present else None


# ---- PostgreSQL -------------------------------------------------------------------------------


@functools.lru_cache(maxsize=4096)
def postgres_sql(sql: str) -> str:
    """``sql`` with ``?`` placeholders as psycopg's ``%s`` (``%`` escaped first)."""
    return sql.replace("%", "%%").replace("?", "%s")


class _PostgresConnection:
    def __init__(self, raw: Any) -> None:
        self.raw = raw

    def _errors(self) -> tuple[type[Exception], type[Exception]]:
        import psycopg

        return psycopg.errors.UniqueViolation, psycopg.Error

    def execute(self, sql: str, args: Sequence[Any] = ()) -> Cursor:
        unique, error = self._errors()
        try:
            cursor: Cursor = self.raw.execute(postgres_sql(sql), tuple(args))
            return cursor
        except unique as exc:
            raise DuplicateRow(_first_line(exc)) from None
        except error as exc:
            raise DatabaseError(_first_line(exc)) from None

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        unique, error = self._errors()
        shape = _multi_row_shape(sql)
        try:
            with self.raw.cursor() as cur:
                if shape is None or len(rows) < 2:
                    cur.executemany(postgres_sql(sql), [tuple(r) for r in rows])
                    return
                for chunk in _chunks(rows, shape.key):
                    cur.execute(shape.sql(len(chunk)),
                                [value for row in chunk for value in row])
        except unique as exc:
            raise DuplicateRow(_first_line(exc)) from None
        except error as exc:
            raise DatabaseError(_first_line(exc)) from None

    def insert(self, sql: str, args: Sequence[Any] = ()) -> int:
        row = self.execute(sql + " RETURNING id", args).fetchone()
        return int(row[0])

    @property
    def lost(self) -> bool:
        """The server closed this connection (it stopped or restarted)."""
        return bool(self.raw.closed or self.raw.broken)

    def begin(self) -> None:
        self.execute("BEGIN")

    def commit(self) -> None:
        self.execute("COMMIT")

    def rollback(self) -> None:
        import psycopg

        if self.raw.closed or self.raw.info.transaction_status == \
                psycopg.pq.TransactionStatus.IDLE:
            return
        self.execute("ROLLBACK")

    def close(self) -> None:
        self.raw.close()


def append_rows(db: Connection, table: str, rows: Sequence[Sequence[Any]]) -> None:
    """Append ``rows`` (every column, in the table's order) to ``table`` (a name from the
    code, never from input): PostgreSQL's ``COPY``, else one ``executemany``. Why: chart
    points are most of what a fleet writes (five of six rows at 1,000 robots), and an
    ``INSERT`` per row through a pipeline cost the server and the driver several times
    what ``COPY`` does. Not inside :func:`write_batch` (COPY leaves no pipeline open)."""
    if not rows:
        return
    if not isinstance(db, _PostgresConnection):
        marks = ", ".join("?" for _ in rows[0])
        db.executemany(f"INSERT INTO {table} VALUES ({marks})", rows)
        return
    unique, error = db._errors()
    try:
        with db.raw.cursor() as cur, cur.copy(f"COPY {table} FROM STDIN") as copy:
            for row in rows:
                copy.write_row(row)
    except unique as exc:
        raise DuplicateRow(_first_line(exc)) from None
    except error as exc:
        raise DatabaseError(_first_line(exc)) from None


@contextlib.contextmanager
def write_batch(db: Connection) -> Iterator[None]:
    """Statements sent inside are pipelined where the engine allows it (PostgreSQL: psycopg's
    pipeline mode), so a flush of many statements costs round trips only where a result is
    read, not one per statement. Why: a flush is dozens of statements (a statement per kind
    of row, each event its own), and on a loaded machine each round trip to the server
    waited milliseconds. Errors come out as :class:`DatabaseError` as they do elsewhere;
    SQLite runs the statements as they come."""
    if not isinstance(db, _PostgresConnection):
        yield
        return
    unique, error = db._errors()
    try:
        with db.raw.pipeline():
            yield
    except unique as exc:
        raise DuplicateRow(_first_line(exc)) from None
    except error as exc:
        raise DatabaseError(_first_line(exc)) from None


MULTI_ROW_MAX = 1000
"""Rows per multi-row ``INSERT`` at most (PostgreSQL takes 65,535 parameters a statement)."""

_INSERT = re.compile(r"INSERT INTO (\w+) \(([^)]*)\) VALUES \((\?(?:, \?)*)\)(.*)",
                     re.DOTALL)
_CONFLICT = re.compile(r"\s*ON CONFLICT \(([^)]*)\) DO UPDATE")


@dataclass(frozen=True, slots=True)
class _MultiRow:
    """An ``INSERT ... VALUES (?, ...) [ON CONFLICT ...]`` sent as one statement of many
    rows; ``key`` the positions of its conflict columns when it updates on conflict."""

    head: str
    row: str
    tail: str
    key: tuple[int, ...]

    def sql(self, n: int) -> str:
        return postgres_sql(f"{self.head} VALUES {', '.join([self.row] * n)}{self.tail}")


@functools.lru_cache(maxsize=256)
def _multi_row_shape(sql: str) -> _MultiRow | None:
    """How to send rows of ``sql`` many to a statement, if it is a plain ``INSERT`` with a
    column list (else ``None``: one execution per row). Why: through psycopg's pipeline
    each row was a statement whose result the driver handled in Python, tens of
    microseconds each holding the interpreter's lock that the station's other threads
    wanted (a flush of 36,000 rows took 1.3-1.7 s alone and 3.5-4 s beside a busy
    thread); a statement of a thousand rows is one result."""
    match = _INSERT.fullmatch(sql.strip())
    if match is None:
        return None
    table, columns, marks, tail = match.groups()
    names = [c.strip() for c in columns.split(",")]
    key: tuple[int, ...] = ()
    conflict = _CONFLICT.match(tail)
    if conflict is not None:
        target = [c.strip() for c in conflict.group(1).split(",")]
        if not set(target) <= set(names):
            return None
        key = tuple(names.index(c) for c in target)
    return _MultiRow(f"INSERT INTO {table} ({columns})", f"({marks})", tail, key)


def _chunks(rows: Sequence[Sequence[Any]], key: tuple[int, ...]) -> Iterator[list[Any]]:
    """``rows`` in order, at most :data:`MULTI_ROW_MAX` a chunk, and with ``key``: a new
    chunk where a row's key is already in the current one (PostgreSQL updates a row once
    per statement), so the chunks applied in order do what the rows one by one did."""
    chunk: list[Any] = []
    seen: set[tuple[Any, ...]] = set()
    for row in rows:
        k = tuple(row[i] for i in key) if key else ()
        if len(chunk) >= MULTI_ROW_MAX or (key and k in seen):
            yield chunk
            chunk, seen = [], set()
        chunk.append(row)
        if key:
            seen.add(k)
    if chunk:
        yield chunk


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


@dataclass(slots=True)
class PostgresDatabase:
    """A PostgreSQL database (``postgresql://user@host:port/name``), shared by every station
    process that names it."""

    url: str
    connect_timeout: float = 5.0
    dialect: str = "postgresql"
    memory: bool = False

    def connect(self, *, read_only: bool = False) -> Connection:
        try:
            import psycopg
        except ImportError:
            raise DatabaseError("PostgreSQL needs psycopg 3: pip install 'psycopg[binary]' "
                                "(the postgresql extra)") from None
        try:
            raw = psycopg.connect(self.url, autocommit=True,
                                  connect_timeout=max(1, int(self.connect_timeout)))
        except psycopg.Error as exc:
            raise DatabaseError(f"{self.describe()}: cannot connect: "
                                f"{_first_line(exc)}") from None
        return _PostgresConnection(raw)

    def table_names(self, db: Connection) -> set[str]:
        return {r[0] for r in db.execute(
            "SELECT tablename FROM pg_tables WHERE schemaname = current_schema()")}

    def size_bytes(self, db: Connection) -> int:
        return int(db.execute("SELECT pg_database_size(current_database())").fetchone()[0])

    def describe(self) -> str:
        return without_password(self.url)


class ReconnectingConnection:
    """A :class:`Connection` that outlives a PostgreSQL server going away and coming back.

    The accounts, tokens, robot keys, alerts and the store's readers each keep one
    connection. When a statement outside a transaction fails because the connection was
    lost (the server restarted), it is run once more on a new connection, so the first
    request after the database returns succeeds; any other failure is raised, after
    dropping a lost connection so the next statement reconnects. SQLite connections are
    kept (a full disk does not break them, and a ``:memory:`` database lives only as long
    as its one connection)."""

    def __init__(self, database: Database, *, read_only: bool = False) -> None:
        self.database = database
        self.read_only = read_only
        self._db: Connection | None = database.connect(read_only=read_only)
        self._in_transaction = False

    def _connection(self) -> Connection:
        if self._db is None:
            self._db = self.database.connect(read_only=self.read_only)
        return self._db

    def _lost(self) -> bool:
        """Forget the connection if the server dropped it; whether it did."""
        if self._db is None or self.database.dialect == "sqlite":
            return False
        if not getattr(self._db, "lost", False):
            return False
        with contextlib.suppress(Exception):
            self._db.close()
        self._db = None
        return True

    def execute(self, sql: str, args: Sequence[Any] = ()) -> Cursor:
        try:
            return self._connection().execute(sql, args)
        except DuplicateRow:
            raise
        except DatabaseError:
            if not self._lost() or self._in_transaction:
                self._in_transaction = False
                raise
        return self._connection().execute(sql, args)  # once more, on a new connection

    def executemany(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        try:
            self._connection().executemany(sql, rows)
        except DuplicateRow:
            raise
        except DatabaseError:
            self._lost()
            self._in_transaction = False
            raise

    def insert(self, sql: str, args: Sequence[Any] = ()) -> int:
        return int(self.execute(sql + " RETURNING id", args).fetchone()[0])

    def begin(self) -> None:
        if self.database.dialect == "sqlite":
            self._connection().begin()  # BEGIN IMMEDIATE
        else:
            self.execute("BEGIN")  # on a new connection if the server dropped the old one
        self._in_transaction = True

    def commit(self) -> None:
        try:
            self.execute("COMMIT")
        finally:
            self._in_transaction = False

    def rollback(self) -> None:
        self._in_transaction = False
        if self._db is not None:
            try:
                self._db.rollback()
            except DatabaseError:
                self._lost()
                raise

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None


def without_password(location: str) -> str:
    """``location`` with the password of a database URL replaced by ``***`` (for messages,
    logs and hints printed to a terminal others may see)."""
    return re.sub(r"://([^:@/]*):[^@/]*@", r"://\1:***@", location)


def open_database(location: str | Path | Database) -> Database:
    """The database named by ``location``: ``postgresql://...``, ``sqlite:///relative.db`` or
    ``sqlite:////absolute.db``, a plain file path or ``:memory:``."""
    if not isinstance(location, str | Path):
        return location
    text = str(location)
    if text.startswith(POSTGRES_SCHEMES):
        return PostgresDatabase(text)
    if text.startswith("sqlite:///"):  # as SQLAlchemy: sqlite:///rel.db, sqlite:////abs.db
        text = text[len("sqlite:///"):] or ":memory:"
    return SqliteDatabase(text)
