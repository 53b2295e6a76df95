"""A robot's log, as fetched by a log request, written out as JSON lines, CSV or MCAP.

Reads go through the store's read protocol only, so every storage backend exports alike.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import IO, Any, Protocol

from blackbox.record.store import LogEntry
from blackbox.station.records import MAX_PAGE, LogRequest


class LogRows(Protocol):
    def log_request(self, request: int) -> LogRequest | None: ...

    def log_entries(self, request: int, offset: int = 0,
                    limit: int = MAX_PAGE) -> list[LogEntry]: ...


def iter_log_entries(store: LogRows, request: int, batch: int = MAX_PAGE) -> Iterator[LogEntry]:
    """Every row of a log request's answer, read in batches (for downloads)."""
    offset = 0
    while True:
        entries = store.log_entries(request, offset, batch)
        if not entries:
            return
        yield from entries
        offset += len(entries)


def export_log(store: LogRows, request: int, fmt: str, out: IO[Any]) -> int:
    """Write a log request's rows to ``out`` as ``jsonl`` or ``csv`` (text stream) or
    ``mcap`` (binary stream); returns the number of entries written."""
    from blackbox.record.export import FORMATS, write_csv, write_jsonl, write_mcap

    info = store.log_request(request)
    if info is None:
        raise LookupError(f"no log request {request}")
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; use one of {', '.join(FORMATS)}")
    entries = iter_log_entries(store, request)
    if fmt == "mcap":
        return write_mcap(entries, out, info.robot_id)
    return (write_jsonl if fmt == "jsonl" else write_csv)(entries, out)
