"""Reading what is left of a damaged health log, page by page, and saying what was lost.

A log cut short (a disk that lost its last blocks, a copy that stopped early) is refused
whole by SQLite: any query that touches a missing page fails. Yet nearly all of it is
intact. This reader does not go through SQLite's B-tree code: it reads the file format
itself (the SQLite documentation's "Database File Format"). It walks each table's B-tree
from its root page, reads every leaf page it can reach, and notes every page it cannot
(beyond the end of the file, or not a B-tree page) with the range of row ids its parent
says it held. Table leaf pages that no walk reached (their parent page was lost) are read
too, and their rows taken where they fill such a lost range; pages on the free list are
never read (their rows were deleted). Frames (schema 4) whose data is intact are decoded;
a frame whose overflow pages are lost is reported with its id and time range.

The WAL, if any, is applied first to a copy (SQLite's own checkpoint works page by page
and does not need the B-trees), so the original files are never written.
"""

from __future__ import annotations

import bisect
import fnmatch
import mmap
import shutil
import sqlite3
import struct
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from blackbox.record.store import (
    KIND_NAMES,
    KINDS,
    LogEntry,
    StorageError,
    _loads,
    frame_entries,
)

TABLES = {"entries": 6, "frames": 10, "channels": 4}
"""The tables salvage reads, with their number of columns (how an orphan page's rows are
recognised)."""


class NotALog(StorageError):
    """The file is not a SQLite database this reader can make sense of."""


@dataclass(frozen=True, slots=True)
class LostRange:
    """Rows of ``table`` with row ids ``first``..``last`` sat on pages that are gone
    (for ``entries`` and ``frames`` row ids are entry ids and frame numbers)."""

    table: str
    first: int
    last: int
    pages: tuple[int, ...]
    ids: tuple[int, int] | None = None
    """For frames: the entry ids their entries had (bounded by the frames around them)."""
    recovered: int = 0
    """Rows of the range found on pages whose parent was lost (so not all of it is lost)."""


@dataclass(frozen=True, slots=True)
class LostFrame:
    """A frame whose row survived but whose data did not."""

    frame: int
    first_id: int | None
    last_id: int | None
    count: int | None
    t_min: float | None
    t_max: float | None


@dataclass(slots=True)
class SalvageReport:
    """What was read and what was lost."""

    page_size: int = 0
    pages_in_file: int = 0
    pages_expected: int = 0
    wal_applied: bool | None = None  # None: there was no WAL
    lost: list[LostRange] = field(default_factory=list)
    lost_frames: list[LostFrame] = field(default_factory=list)
    payloads_lost: list[int] = field(default_factory=list)  # entry ids, payload unreadable
    orphan_rows: int = 0
    rows: int = 0
    frames: int = 0
    frame_entries: int = 0

    @property
    def damaged(self) -> bool:
        return bool(self.lost or self.lost_frames or self.payloads_lost) or \
            self.pages_in_file < self.pages_expected

    def lines(self, entries: Sequence[LogEntry]) -> list[str]:
        """The report for a person: what was read, then each loss."""
        out = [f"salvaged {self.rows + self.frame_entries} entries ({self.rows} rows, "
               f"{self.frame_entries} in {self.frames} frames)" + _span(entries)]
        if self.pages_in_file < self.pages_expected:
            out.append(f"the file ends after page {self.pages_in_file} of "
                       f"{self.pages_expected} ({self.page_size}-byte pages): "
                       f"{self.pages_expected - self.pages_in_file} "
                       f"page{'s' if self.pages_expected - self.pages_in_file > 1 else ''} "
                       "missing")
        if self.wal_applied is False:
            out.append("the WAL beside the log could not be applied; read without it")
        by_id = sorted(entries, key=lambda e: e.id)
        for lost in _merged(self.lost):
            if lost.recovered:
                out.append(f"{lost.table}: {lost.recovered} rows of the range below were "
                           "found on pages whose parent page was lost; the rest is lost")
            if lost.table not in ("entries", "frames"):
                rows = "rows" if lost.last >= 2**62 else f"rows {lost.first}..{lost.last}"
                out.append(f"lost: {lost.table} {rows} (pages {_pages(lost.pages)})")
                continue
            if lost.table == "entries":
                out.append(f"lost: entry ids {lost.first}..{_end(lost.last)} stored as rows "
                           f"(pages {_pages(lost.pages)})"
                           + _between(by_id, lost.first, lost.last))
                continue
            ids = "" if lost.ids is None else \
                f": their entries have ids from {lost.ids[0]} on"
            out.append(f"lost: frames {lost.first}..{_end(lost.last)} "
                       f"(pages {_pages(lost.pages)}){ids}")
        for frame in self.lost_frames:
            span = "" if frame.t_min is None else f", time {frame.t_min!r}..{frame.t_max!r}"
            out.append(f"lost: frame {frame.frame} data ({frame.count} entries, ids "
                       f"{frame.first_id}..{frame.last_id}{span})")
        if self.payloads_lost:
            out.append(f"lost: the payload of {len(self.payloads_lost)} entries (ids "
                       f"{_short(self.payloads_lost)}); kept with payload "
                       "{\"salvage\": \"payload lost\"}")
        if not self.damaged:
            out.append("nothing lost")
        return out


@dataclass(slots=True)
class Salvaged:
    entries: list[LogEntry]
    robot_id: str
    report: SalvageReport


def _merged(ranges: Sequence[LostRange]) -> list[LostRange]:
    """Adjacent lost ranges of one table as one (a truncated file loses runs of pages)."""
    out: list[LostRange] = []
    for r in sorted(ranges, key=lambda r: (r.table, r.first)):
        if out and out[-1].table == r.table and out[-1].last + 1 >= r.first:
            last = out[-1]
            ids = None if last.ids is None or r.ids is None else \
                (min(last.ids[0], r.ids[0]), max(last.ids[1], r.ids[1]))
            out[-1] = LostRange(r.table, last.first, max(last.last, r.last),
                                last.pages + r.pages, ids, last.recovered + r.recovered)
        else:
            out.append(r)
    return out


def _end(last: int) -> str:
    return "end" if last >= 2**62 else str(last)


def _pages(pages: Sequence[int]) -> str:
    return _short(sorted(pages))


def _short(numbers: Sequence[int]) -> str:
    text = ", ".join(map(str, numbers[:8]))
    return text + (f", ... ({len(numbers)} in all)" if len(numbers) > 8 else "")


def _span(entries: Sequence[LogEntry]) -> str:
    if not entries:
        return ""
    return f", time {min(e.time for e in entries)!r}..{max(e.time for e in entries)!r}"


def _between(by_id: Sequence[LogEntry], first: int, last: int) -> str:
    """The times of the salvaged entries just before and after ids ``first``..``last``."""
    ids = [e.id for e in by_id]
    before = bisect.bisect_left(ids, first) - 1
    after = bisect.bisect_right(ids, last)
    t0 = f"{by_id[before].time!r}" if before >= 0 else "the start"
    t1 = f"{by_id[after].time!r}" if after < len(by_id) else "the end"
    return f", between time {t0} and {t1}"


# ---- the file format ---------------------------------------------------------------------------


class _Gone(StorageError):
    """A page needed for a value is missing."""


def _varint(buf: bytes | mmap.mmap, at: int) -> tuple[int, int]:
    value = 0
    for i in range(8):
        byte = buf[at + i]
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, at + i + 1
    return (value << 8) | buf[at + 8], at + 9


def _value(serial: int, raw: bytes) -> Any:
    if serial == 0:
        return None
    if 1 <= serial <= 6:
        return int.from_bytes(raw, "big", signed=True)
    if serial == 7:
        return struct.unpack(">d", raw)[0]
    if serial in (8, 9):
        return serial - 8
    if serial % 2 == 0:
        return bytes(raw)
    return raw.decode("utf-8", "replace")


_SIZES = {0: 0, 1: 1, 2: 2, 3: 3, 4: 4, 5: 6, 6: 8, 7: 8, 8: 0, 9: 0}


def _size(serial: int) -> int:
    return _SIZES[serial] if serial < 12 else (serial - 12) // 2


class _File:
    """The pages of one database file."""

    def __init__(self, data: mmap.mmap | bytes) -> None:
        self.data = data
        if len(data) < 100 or not bytes(data[:16]) == b"SQLite format 3\x00":
            raise NotALog("not a SQLite database")
        size = int.from_bytes(data[16:18], "big")
        self.page_size = 65536 if size == 1 else size
        if self.page_size < 512 or self.page_size & (self.page_size - 1):
            raise NotALog(f"page size {self.page_size} in the header is not one SQLite uses")
        if data[56:60] not in (b"\x00\x00\x00\x00", b"\x00\x00\x00\x01"):
            raise NotALog("text encoding is not UTF-8")
        self.usable = self.page_size - data[20]
        self.pages = len(data) // self.page_size
        self.expected = int.from_bytes(data[28:32], "big") or self.pages
        self.autovacuum = int.from_bytes(data[52:56], "big") != 0

    def page(self, number: int) -> bytes | None:
        if not 1 <= number <= self.pages:
            return None
        start = (number - 1) * self.page_size
        return bytes(self.data[start:start + self.page_size])

    def free_pages(self) -> set[int]:
        free: set[int] = set()
        trunk = int.from_bytes(self.data[32:36], "big")
        while trunk and trunk not in free:
            page = self.page(trunk)
            if page is None:
                break
            free.add(trunk)
            count = int.from_bytes(page[4:8], "big")
            for i in range(min(count, (self.usable - 8) // 4)):
                free.add(int.from_bytes(page[8 + 4 * i:12 + 4 * i], "big"))
            trunk = int.from_bytes(page[0:4], "big")
        return free

    def ptrmap_pages(self) -> set[int]:
        if not self.autovacuum:
            return set()
        step = self.usable // 5 + 1
        return set(range(2, self.pages + 1, step))

    def payload(self, page: bytes, at: int, total: int) -> tuple[bytes, bool]:
        """A cell's payload of ``total`` bytes starting at ``at``; ``False`` when part of
        it was on overflow pages that are gone (the bytes read so far are returned)."""
        x = self.usable - 35
        if total <= x:
            return page[at:at + total], True
        m = (self.usable - 12) * 32 // 255 - 23
        k = m + (total - m) % (self.usable - 4)
        local = k if k <= x else m
        parts = [page[at:at + local]]
        have = local
        next_page = int.from_bytes(page[at + local:at + local + 4], "big")
        seen: set[int] = set()
        while have < total:
            overflow = self.page(next_page) if next_page not in seen else None
            if overflow is None:
                return b"".join(parts), False
            seen.add(next_page)
            take = min(total - have, self.usable - 4)
            parts.append(overflow[4:4 + take])
            have += take
            next_page = int.from_bytes(overflow[0:4], "big")
        return b"".join(parts), True

    def leaf_cells(self, number: int, page: bytes) -> Iterator[tuple[int, list[Any], bool]]:
        """``(rowid, values, complete)`` of each cell of a table leaf page; values that
        lie on lost overflow pages are missing from the end of ``values``."""
        head = 100 if number == 1 else 0
        cells = int.from_bytes(page[head + 3:head + 5], "big")
        for i in range(cells):
            at = int.from_bytes(page[head + 8 + 2 * i:head + 10 + 2 * i], "big")
            try:
                total, at = _varint(page, at)
                rowid, at = _varint(page, at)
                raw, complete = self.payload(page, at, total)
                yield rowid, _record(raw), complete
            except (IndexError, KeyError, ValueError):
                continue

    @staticmethod
    def kind(number: int, page: bytes) -> int:
        return page[100 if number == 1 else 0]


def _record(raw: bytes) -> list[Any]:
    header, at = _varint(raw, 0)
    serials: list[int] = []
    while at < header:
        serial, at = _varint(raw, at)
        serials.append(serial)
    values: list[Any] = []
    at = header
    for serial in serials:
        size = _size(serial)
        if at + size > len(raw):
            break  # the rest is on a lost overflow page
        values.append(_value(serial, raw[at:at + size]))
        at += size
    return values


@dataclass(slots=True)
class _Table:
    rows: dict[int, tuple[list[Any], bool]] = field(default_factory=dict)
    lost: list[LostRange] = field(default_factory=list)
    orphans: list[int] = field(default_factory=list)  # row ids found on orphan pages


def _recovered(lost: LostRange, table: _Table) -> LostRange:
    found = sum(lost.first <= rowid <= lost.last for rowid in table.orphans)
    return LostRange(lost.table, lost.first, lost.last, lost.pages, lost.ids, found)


def _walk(db: _File, name: str, root: int, visited: set[int]) -> _Table:
    """Every row reachable from ``root``, and the row id ranges of the pages that are not."""
    table = _Table()
    stack: list[tuple[int, int, int]] = [(root, -(2**63), 2**63 - 1)]
    while stack:
        number, low, high = stack.pop()
        page = db.page(number) if number not in visited else None
        kind = db.kind(number, page) if page is not None else 0
        if page is None or kind not in (5, 13):
            table.lost.append(LostRange(name, max(low, 1), high, (number,)))
            continue
        visited.add(number)
        head = 100 if number == 1 else 0
        if kind == 13:
            for rowid, values, complete in db.leaf_cells(number, page):
                table.rows[rowid] = (values, complete)
            continue
        cells = int.from_bytes(page[head + 3:head + 5], "big")
        previous = low
        children: list[tuple[int, int, int]] = []
        for i in range(cells):
            at = int.from_bytes(page[head + 12 + 2 * i:head + 14 + 2 * i], "big")
            try:
                child = int.from_bytes(page[at:at + 4], "big")
                key, _ = _varint(page, at + 4)
            except IndexError:
                continue
            children.append((child, previous, key))
            previous = key + 1
        children.append((int.from_bytes(page[head + 8:head + 12], "big"), previous, high))
        stack.extend(reversed(children))
    return table


def _schema(db: _File, visited: set[int]) -> dict[str, int]:
    """Root pages of the tables, from ``sqlite_master`` (page 1)."""
    master = _walk(db, "sqlite_master", 1, visited)
    roots: dict[str, int] = {}
    for values, _ in master.rows.values():
        if len(values) >= 4 and values[0] == "table" and isinstance(values[3], int):
            roots[str(values[1])] = values[3]
    return roots


def _orphans(db: _File, visited: set[int], tables: dict[str, _Table]) -> int:
    """Rows of leaf pages no walk reached, where they fill a range known to be lost."""
    skip = visited | db.free_pages() | db.ptrmap_pages()
    found = 0
    for number in range(1, db.pages + 1):
        if number in skip:
            continue
        page = db.page(number)
        if page is None or db.kind(number, page) != 13:
            continue
        for rowid, values, complete in db.leaf_cells(number, page):
            for name, table in tables.items():
                columns = TABLES.get(name)
                if columns is None or len(values) not in range(1, columns + 1) or \
                        (complete and len(values) != columns) or values[0] is not None:
                    continue
                if rowid in table.rows or not any(r.first <= rowid <= r.last
                                                  for r in table.lost):
                    continue
                table.rows[rowid] = (values, complete)
                table.orphans.append(rowid)
                found += 1
                break
    return found


def _with_wal(path: Path, scratch: Path) -> tuple[Path, bool | None]:
    """A copy of the log with its WAL applied (``None``: it had none)."""
    wal = Path(f"{path}-wal")
    if not wal.exists() or wal.stat().st_size == 0:
        return path, None
    copy = scratch / path.name
    shutil.copyfile(path, copy)
    shutil.copyfile(wal, Path(f"{copy}-wal"))
    try:
        db = sqlite3.connect(copy, isolation_level=None)
        try:
            busy, _, _ = db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
        finally:
            db.close()
    except sqlite3.Error:
        return path, False
    return copy, busy == 0


def salvage(path: Path) -> Salvaged:
    """Every intact entry of the log at ``path``, in time order, and what was lost.

    Raises :class:`NotALog` when the file is not a SQLite database at all.
    """
    with tempfile.TemporaryDirectory(prefix="blackbox-salvage-") as scratch:
        source, wal_applied = _with_wal(path, Path(scratch))
        with source.open("rb") as fh:
            if source.stat().st_size == 0:
                raise NotALog("the file is empty")
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return _salvage(_File(data), wal_applied)


def _salvage(db: _File, wal_applied: bool | None) -> Salvaged:
    report = SalvageReport(page_size=db.page_size, pages_in_file=db.pages,
                           pages_expected=max(db.expected, db.pages), wal_applied=wal_applied)
    visited: set[int] = set()
    roots = _schema(db, visited)
    tables = {name: _walk(db, name, roots[name], visited) if name in roots else _Table()
              for name in (*TABLES, "meta")}
    report.orphan_rows = _orphans(db, visited, tables)
    for name in ("entries", "frames", "channels", "meta"):
        report.lost += [r for r in tables[name].lost
                        if not _refilled(r, tables[name])]
    report.lost = [_with_ids(r, tables["frames"]) if r.table == "frames" else r
                   for r in report.lost]
    report.lost = [_recovered(r, tables[r.table]) for r in report.lost]
    channels = {rowid: values for rowid, (values, _) in tables["channels"].rows.items()
                if len(values) >= 3}
    meta = {str(v[0]): v[1] for v, _ in tables["meta"].rows.values() if len(v) == 2}
    entries: list[LogEntry] = []
    for rowid, (values, complete) in sorted(tables["entries"].rows.items()):
        entry = _entry(rowid, values, complete, channels)
        if entry is None:
            continue
        if not complete or len(values) < 6:
            report.payloads_lost.append(rowid)
        entries.append(entry)
    report.rows = len(entries)
    for rowid, (values, complete) in sorted(tables["frames"].rows.items()):
        decoded = _frame(values, complete, channels)
        if decoded is None:
            report.lost_frames.append(_lost_frame(rowid, values))
            continue
        entries += decoded
        report.frames += 1
        report.frame_entries += len(decoded)
    entries.sort(key=lambda e: (e.time, e.id))
    return Salvaged(entries, str(meta.get("robot_id") or ""), report)


def _with_ids(lost: LostRange, frames: _Table) -> LostRange:
    """Frames are numbered in the order they were written, and a frame's first id is above
    the first id of every frame before it (later commits have higher ids; within a commit
    groups are written in the order of their first entry). Their last ids interleave
    within a commit, so only the lower bound is known."""
    before = [v[1] for rowid, (v, _) in frames.rows.items()
              if rowid < lost.first and len(v) > 1 and isinstance(v[1], int)]
    return LostRange(lost.table, lost.first, lost.last, lost.pages,
                     (max(before, default=0) + 1, 2**63 - 1))


def _refilled(lost: LostRange, table: _Table) -> bool:
    """Whether orphan pages gave back rows for the whole of a lost range: it stays
    reported unless every id in it is back (ranges with no upper bound stay)."""
    if lost.last - lost.first > 1_000_000:
        return False
    return all(i in table.rows for i in range(lost.first, lost.last + 1))


def _entry(rowid: int, values: list[Any], complete: bool,
           channels: dict[int, list[Any]]) -> LogEntry | None:
    if len(values) < 3 or not isinstance(values[1], float | int) or \
            not isinstance(values[2], int):
        return None
    channel = channels.get(values[3]) if len(values) > 3 and values[3] is not None else None
    code = values[4] if len(values) > 4 and isinstance(values[4], int) else None
    payload: dict[str, Any]
    if complete and len(values) >= 6 and isinstance(values[5], str):
        payload = _loads(values[5])
    else:
        payload = {"salvage": "payload lost"}
    return LogEntry(rowid, float(values[1]), KIND_NAMES.get(values[2], f"kind{values[2]}"),
                    channel[1] if channel else None, channel[2] if channel else None, code,
                    payload)


def _frame(values: list[Any], complete: bool,
           channels: dict[int, list[Any]]) -> list[LogEntry] | None:
    if not complete or len(values) != 10 or not isinstance(values[9], bytes):
        return None
    channel = channels.get(values[5]) if values[5] is not None else None
    try:
        return frame_entries((int(values[4]), channel[1] if channel else None,
                              channel[2] if channel else None, float(values[6]),
                              int(values[8]), values[9]))
    except Exception:  # any damage inside the data: the frame is lost, reported
        return None


def _lost_frame(rowid: int, values: list[Any]) -> LostFrame:
    def get(i: int) -> Any:
        return values[i] if len(values) > i else None
    return LostFrame(rowid, get(1), get(2), get(3), get(6), get(7))


def select(entries: Sequence[LogEntry], entity: str | None = None,
           characteristic: str | None = None, start: float | None = None,
           end: float | None = None, kinds: Sequence[str] | None = None,
           limit: int | None = None) -> list[LogEntry]:
    """The filters of :meth:`~blackbox.record.store.Store.query`, on salvaged entries."""
    if kinds:
        unknown = [k for k in kinds if k not in KINDS]
        if unknown:
            raise ValueError(f"unknown kind {unknown[0]!r}; known: {', '.join(KINDS)}")

    def match(value: str | None, pattern: str | None) -> bool:
        if pattern is None:
            return True
        if value is None:
            return False
        if any(ch in pattern for ch in "*?["):
            return fnmatch.fnmatchcase(value, pattern)
        return value == pattern

    out: list[LogEntry] = []
    for e in entries:
        if (start is not None and e.time < start) or (end is not None and e.time > end):
            continue
        if kinds and e.kind not in kinds:
            continue
        if match(e.entity, entity) and match(e.characteristic, characteristic):
            out.append(e)
            if limit is not None and len(out) >= limit:
                break
    return out

