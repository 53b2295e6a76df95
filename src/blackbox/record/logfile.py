"""Which file the recorder may write, and what it may do with one that is already there.

A flight recorder must never destroy what it did not write. Before the recorder opens its
path, :func:`check_record_path` refuses what cannot hold a log (a directory, a device, a
file under ``/proc``, a path whose parent is a file) and any existing file that is not a
health log of this project: such a file is left exactly as it is unless the operator says
``--force``, and even then it is renamed aside, never overwritten. Only a health log of
this project that turns out corrupt is moved aside automatically (:func:`set_aside`).

A health log is recognised by reading the file through SQLite (read-only, its WAL
included): the ``application_id`` this project writes (:data:`APPLICATION_ID`), or, for
logs written before it was set, a schema version this project knows plus its three
tables. Only a file SQLite cannot read is judged by its first 100 bytes (the header).

Identifiers that become file names (the robot id in a snapshot's name) go through
:func:`safe_name`, so ``robot.id: ../../x`` cannot leave the snapshot directory.
"""

from __future__ import annotations

import os
import re
import sqlite3
import stat
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal

from blackbox.record.store import APPLICATION_ID, SCHEMA_VERSION, StorageError

SQLITE_MAGIC = b"SQLite format 3\x00"
PSEUDO_FILESYSTEMS = frozenset({"proc", "sysfs", "devtmpfs", "devpts", "cgroup", "cgroup2",
                                "debugfs", "tracefs", "securityfs", "pstore", "bpf",
                                "configfs", "fusectl", "mqueue", "hugetlbfs", "binfmt_misc"})
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")

Kind = Literal["missing", "empty", "health_log", "foreign"]


class RecordPathError(StorageError):
    """The record path cannot be used; the message says why and what to do."""


def safe_name(text: str, fallback: str = "robot", limit: int = 64) -> str:
    """``text`` as one harmless file name component: ``[A-Za-z0-9._-]``, no leading dot."""
    name = _UNSAFE.sub("_", text).strip("._-")[:limit]
    return name or fallback


def classify(path: Path) -> Kind:
    """What is at ``path``: nothing, an empty file, a health log of ours, or anything else.

    Read through SQLite (read-only, WAL included): a log whose header and tables are still
    only in its WAL (a log made before the header was durable from creation, cut short by
    a crash) is a health log all the same. The header bytes decide only when SQLite cannot
    read the file: non-SQLite content is foreign, a damaged database with this project's
    application id in its header is a health log of ours (that the writer moves aside).
    """
    try:
        with path.open("rb") as fh:
            head = fh.read(100)
    except FileNotFoundError:
        return "missing"
    except OSError:
        return "foreign"
    if not head:
        # An empty main file beside a WAL with content: SQLite would discard that WAL
        # on opening, so it is not ours to take (it cannot come from this recorder).
        return "foreign" if _size(Path(f"{path}-wal")) > 0 else "empty"
    if _rolls_back_to_nothing(path) and _identity(path) is None:
        # Killed while being created (pages of the first transaction, even page 1, may
        # be missing): the next open rolls it back to the empty file it was.
        return "empty"
    if len(head) < 100 or not head.startswith(SQLITE_MAGIC):
        return "foreign"
    identity = _identity(path)
    if identity is None:  # SQLite cannot read it: the header alone tells
        user_version = int.from_bytes(head[60:64], "big")
        application_id = int.from_bytes(head[68:72], "big")
        if application_id == APPLICATION_ID:
            return "health_log"
        # A pre-application-id log of ours that is corrupt: the schema version matched.
        return "health_log" if application_id == 0 and 1 <= user_version <= SCHEMA_VERSION \
            else "foreign"
    application_id, user_version, tables = identity
    if application_id == APPLICATION_ID:
        return "health_log"
    if application_id != 0 or not 1 <= user_version <= SCHEMA_VERSION:
        return "foreign"
    return "health_log" if {"meta", "channels", "entries"} <= tables else "foreign"


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


JOURNAL_MAGIC = bytes.fromhex("d9d505f920a163d7")


def _rolls_back_to_nothing(path: Path) -> bool:
    """A hot rollback journal beside ``path`` whose database was empty when its
    transaction began (journal header: initial size 0 pages): what was committed is an
    empty file. A read-only connection may not roll it back, so this reads the journal."""
    try:
        with Path(f"{path}-journal").open("rb") as fh:
            head = fh.read(28)
    except OSError:
        return False
    return len(head) == 28 and head.startswith(JOURNAL_MAGIC) and \
        int.from_bytes(head[16:20], "big") == 0


def _identity(path: Path) -> tuple[int, int, set[str]] | None:
    """``application_id``, ``user_version`` and table names as SQLite reads them, WAL
    included; ``None`` when it cannot (not a database, damaged, a hot journal it may not
    roll back read-only)."""
    # Without a WAL there is nothing to read but the main file: ``immutable`` reads it
    # without creating the -wal and -shm files a WAL reader needs (no litter beside a
    # file that may not be ours).
    uri = f"{path.resolve().as_uri()}?mode=ro"
    if _size(Path(f"{path}-wal")) == 0:
        uri += "&immutable=1"
    try:
        db = sqlite3.connect(uri, uri=True, timeout=5.0)
        try:
            application_id = int(db.execute("PRAGMA application_id").fetchone()[0])
            user_version = int(db.execute("PRAGMA user_version").fetchone()[0])
            tables = {str(r[0]) for r in
                      db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            db.close()
    except sqlite3.Error:
        return None
    return application_id, user_version, tables


def _filesystem_of(path: Path) -> str | None:
    """The file system type of the mount holding ``path`` (Linux), else ``None``."""
    try:
        mounts = Path("/proc/self/mounts").read_text().splitlines()
    except OSError:
        return None
    best, kind = "", None
    target = str(path)
    for line in mounts:
        parts = line.split()
        if len(parts) < 3:
            continue
        point = parts[1].replace("\\040", " ")
        inside = target == point or target.startswith(point.rstrip("/") + "/")
        if inside and len(point) > len(best):
            best, kind = point, parts[2]
    return kind


def check_record_path(path: Path, *, replace_foreign: bool = False) -> Path | None:
    """Make sure the health log can live at ``path``.

    The directory must exist: creating it could put the log on the wrong disk (a mount
    point whose disk is not mounted is just an empty directory's missing child). Raises
    :class:`RecordPathError` with a message for the operator when it cannot. With
    ``replace_foreign`` a file that is not a health log is renamed aside (the new name is
    returned) instead of refused.
    """
    path = Path(os.path.abspath(path))
    for parent in reversed(path.parents):
        if parent.exists() and not parent.is_dir():
            raise RecordPathError(f"{path}: {parent} is not a directory")
    fs = _filesystem_of(path)
    if fs in PSEUDO_FILESYSTEMS:
        raise RecordPathError(f"{path}: is on the {fs} pseudo file system, which cannot hold a "
                              "health log; choose a path on a disk")
    try:
        info = path.stat()
    except FileNotFoundError:
        info = None
    except OSError as exc:
        raise RecordPathError(f"{path}: cannot use it: {exc.strerror}") from None
    if info is not None:
        if stat.S_ISDIR(info.st_mode):
            raise RecordPathError(f"{path}: is a directory; give the health log's file name, "
                                  f"for example {path / 'blackbox.db'}")
        if not stat.S_ISREG(info.st_mode):
            raise RecordPathError(f"{path}: is not a regular file")
    if not path.parent.is_dir():
        raise RecordPathError(f"{path}: directory {path.parent} does not exist; create it "
                              "first (the black box does not guess where its disk is)")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise RecordPathError(f"{path}: directory {path.parent} is not writable")
    if classify(path) != "foreign":
        return None
    if not replace_foreign:
        raise RecordPathError(f"{path}: exists and is not a health log of this black box; "
                              "it was left untouched. Choose another path, or pass --force to "
                              "move it aside and start a new log")
    try:
        return set_aside(path, label="replaced")
    except OSError as exc:
        raise RecordPathError(f"{path}: cannot move it aside: {exc.strerror}") from None


def set_aside(path: Path, now: float | None = None, label: str = "corrupt") -> Path:
    """Rename ``path`` (and its WAL files) out of the way; returns the new name."""
    stamp = datetime.fromtimestamp(now if now is not None else datetime.now(UTC).timestamp(),
                                   UTC)
    aside = path.with_name(f"{path.name}.{label}-{stamp:%Y%m%dT%H%M%SZ}")
    n = 1
    while aside.exists():
        aside = path.with_name(f"{path.name}.{label}-{stamp:%Y%m%dT%H%M%SZ}-{n}")
        n += 1
    path.rename(aside)
    for suffix in ("-wal", "-shm"):
        extra = Path(f"{path}{suffix}")
        if extra.exists():
            extra.rename(Path(f"{aside}{suffix}"))
    return aside
