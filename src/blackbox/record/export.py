"""Getting the health log out: JSON lines, CSV, and MCAP that Foxglove opens.

In MCAP every entry kind is one channel (``/blackbox/<kind>``) of JSON messages with a
JSON schema, logged at the entry's time, so Foxglove can plot, for example,
``/blackbox/sample.payload.values.period{entity=="/usb_cam/image_raw"}``.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

from blackbox.record.store import LogEntry, dumps
from blackbox.safetext import csv_cell

FORMATS = ("jsonl", "csv", "mcap")

ENTRY_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "blackbox.LogEntry",
    "description": "One entry of the robotic black box health log.",
    "type": "object",
    "properties": {
        "id": {"type": "integer", "description": "unique, increasing entry number"},
        "time": {"type": "number", "description": "seconds on the source clock"},
        "kind": {"type": "string"},
        "entity": {"type": ["string", "null"], "description": "node or topic"},
        "characteristic": {"type": ["string", "null"], "description": "observer type"},
        "code": {"type": ["integer", "null"], "description": "observation code, < 0 faulty"},
        "payload": {"type": "object"},
    },
    "required": ["id", "time", "kind", "payload"],
}

CSV_COLUMNS = ("id", "time", "kind", "entity", "characteristic", "code", "payload")


def write_jsonl(entries: Iterable[LogEntry], out: IO[str]) -> int:
    n = 0
    for e in entries:
        out.write(dumps(e.to_dict()))
        out.write("\n")
        n += 1
    return n


def write_csv(entries: Iterable[LogEntry], out: IO[str]) -> int:
    """One row per entry; the payload is a JSON object in the last column. Text cells a
    spreadsheet would run as a formula are neutralised (:func:`blackbox.safetext.csv_cell`):
    entity names come from the robot."""
    writer = csv.writer(out)
    writer.writerow(CSV_COLUMNS)
    n = 0
    for e in entries:
        writer.writerow([e.id, repr(e.time), *map(csv_cell, (e.kind, e.entity or "",
                                                              e.characteristic or "")),
                         "" if e.code is None else e.code, csv_cell(dumps(e.payload))])
        n += 1
    return n


def write_mcap(entries: Iterable[LogEntry], out: IO[bytes], robot_id: str = "") -> int:
    from mcap.writer import CompressionType, Writer

    writer = Writer(out, compression=CompressionType.ZSTD)
    writer.start(profile="", library="blackbox")
    schema_id = writer.register_schema("blackbox.LogEntry", "jsonschema",
                                       json.dumps(ENTRY_SCHEMA).encode())
    channels: dict[str, int] = {}
    n = 0
    for e in entries:
        cid = channels.get(e.kind)
        if cid is None:
            cid = writer.register_channel(f"/blackbox/{e.kind}", "json", schema_id,
                                          {"robot_id": robot_id} if robot_id else {})
            channels[e.kind] = cid
        stamp = max(0, int(e.time * 1e9))
        writer.add_message(cid, stamp, dumps(e.to_dict()).encode(), stamp, sequence=e.id)
        n += 1
    writer.finish()
    return n


def export(entries: Iterable[LogEntry], path: Path | None, fmt: str, robot_id: str = "",
           stdout: IO[str] | None = None) -> int:
    """Write ``entries`` to ``path`` (``None``: ``stdout``, text formats only)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; use one of {', '.join(FORMATS)}")
    if fmt == "mcap":
        if path is None:
            raise ValueError("MCAP is binary: give an output file")
        with path.open("wb") as fh:
            return write_mcap(entries, fh, robot_id)
    write = write_jsonl if fmt == "jsonl" else write_csv
    if path is None:
        assert stdout is not None
        return write(entries, stdout)
    with path.open("w", encoding="utf-8", newline="") as fh:
        return write(entries, fh)


def read_jsonl(lines: Iterable[str]) -> list[LogEntry]:
    """Entries back from JSON lines (for tests and for re-importing an export)."""
    out: list[LogEntry] = []
    for line in lines:
        if line.strip():
            d = json.loads(line)
            out.append(LogEntry(int(d["id"]), float(d["time"]), str(d["kind"]), d.get("entity"),
                                d.get("characteristic"), d.get("code"), d.get("payload") or {}))
    return out
