"""``blackbox log check``: is the health log intact, and if not, what of it can be read.

Intact means: SQLite's ``PRAGMA integrity_check`` finds nothing, every frame decodes
to as many entries as its row says, and the counts and time range can be read. A log
that is not intact is also read page by page (:mod:`blackbox.record.salvage`), so the
report says what ``log query --salvage`` would recover and what is lost. The log is
only read (a WAL is applied to a scratch copy).
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

from blackbox.record.salvage import NotALog, salvage
from blackbox.record.store import SCHEMA_VERSION, StorageError, Store, decode_frame

MESSAGES = 20
"""At most this many problems of ``integrity_check`` are printed."""


@dataclass(slots=True)
class CheckResult:
    intact: bool = True
    lines: list[str] = field(default_factory=list)

    def damaged(self, line: str) -> None:
        self.intact = False
        self.lines.append(line)


def check_log(path: Path) -> CheckResult:
    """The integrity report of the health log at ``path`` (a health log of ours)."""
    result = CheckResult()
    wal = Path(f"{path}-wal")
    wal_size = wal.stat().st_size if wal.exists() else 0
    result.lines.append(f"{path}: {path.stat().st_size} bytes, WAL {wal_size} bytes")
    try:
        with Store.open(path, readonly=True, check=False) as store:
            _read(store, result)
    except (StorageError, sqlite3.DatabaseError) as exc:
        result.damaged(f"unreadable through SQLite: {exc}")
    if result.intact:
        result.lines.append("intact")
        return result
    try:
        found = salvage(path)
    except (NotALog, OSError) as exc:
        result.lines.append(f"salvage: impossible: {exc}")
    else:
        result.lines += [f"salvage: {line}" for line in found.report.lines(found.entries)]
    result.lines.append("damaged: read what is intact with blackbox log query/export "
                        "--salvage")
    return result


def _read(store: Store, result: CheckResult) -> None:
    version = store.schema_version
    page = store.execute("PRAGMA page_size").fetchone()[0]
    pages = store.execute("PRAGMA page_count").fetchone()[0]
    result.lines.append(f"schema {version} (this blackbox writes {SCHEMA_VERSION}), "
                        f"{pages} pages of {page} bytes")
    problems = [str(r[0]) for r in
                store.execute(f"PRAGMA integrity_check({MESSAGES})").fetchall()]
    if problems == ["ok"]:
        result.lines.append("integrity_check: ok")
    else:
        result.damaged(f"integrity_check: {len(problems)} problems"
                       + (" (first 20)" if len(problems) >= MESSAGES else "") + ":")
        result.lines += [f"  {p}" for p in problems]
    try:
        _contents(store, result, version)
    except sqlite3.DatabaseError as exc:
        result.damaged(f"reading the entries failed: {exc}")


def _contents(store: Store, result: CheckResult, version: int) -> None:
    rows, first, last, t0, t1 = store.execute(
        "SELECT count(*), min(id), max(id), min(time), max(time) FROM entries").fetchone()
    framed = frames = 0
    bad: list[str] = []
    if version >= 4:
        cursor = store.execute("SELECT id, count, data, first_id, last_id, t_min, t_max "
                               "FROM frames")
        for fid, count, data, f_first, f_last, f_t0, f_t1 in cursor:
            frames += 1
            framed += count
            first = f_first if first is None else min(first, f_first)
            last = f_last if last is None else max(last, f_last)
            t0 = f_t0 if t0 is None else min(t0, f_t0)
            t1 = f_t1 if t1 is None else max(t1, f_t1)
            try:
                ids, _ = decode_frame(data)
            except Exception as exc:  # any damage inside the data
                bad.append(f"frame {fid} (ids {f_first}..{f_last}): {type(exc).__name__}")
                continue
            if len(ids) != count:
                bad.append(f"frame {fid}: holds {len(ids)} entries, its row says {count}")
    result.lines.append(f"entries: {rows + framed} ({rows} rows, {framed} in {frames} "
                        f"frames), ids {first}..{last}")
    result.lines.append("time range: " + ("none" if t0 is None else f"{t0!r}..{t1!r}"))
    if version >= 4:
        if bad:
            result.damaged(f"frames: {frames - len(bad)} decodable, {len(bad)} not:")
            result.lines += [f"  {b}" for b in bad[:MESSAGES]]
        else:
            result.lines.append(f"frames: {frames} decodable, 0 not")
