"""A rosbag2 directory (``metadata.yaml`` plus storage files), sqlite3 or MCAP storage.

MCAP storage files are plain MCAP files with ``cdr`` channels and are read front to back
like any MCAP file (so a file cut off mid-record replays up to the damage). SQLite storage
is read with ``rosbags`` in timestamp order; SQLite has no meaningful byte offsets, so
damage there is reported with the time of the last message read. rosbag2 records no
publishers: every topic gets the placeholder publisher (docs/bags.md).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path

import yaml

from blackbox.sources.bag.mcapfile import McapScanner
from blackbox.sources.bag.records import BagCorrupt, Item, RecordedMessage, RecordedTopic


def storage_of(path: Path) -> tuple[str, list[Path]]:
    """The storage identifier (``sqlite3``/``mcap``) and data files of a rosbag2 directory."""
    meta_path = path / "metadata.yaml"
    try:
        meta = yaml.safe_load(meta_path.read_text(encoding="utf-8"))
        info = meta["rosbag2_bagfile_information"]
        storage = str(info["storage_identifier"])
        files = [path / str(f) for f in info["relative_file_paths"]]
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise BagCorrupt(str(meta_path), None, f"unreadable rosbag2 metadata: {exc!r}"
                         ) from None
    return storage, files


class Rosbag2Scanner:
    """Items of a rosbag2 directory; ``scan()`` raises :class:`BagCorrupt` at damage."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.storage, self.files = storage_of(path)
        if self.storage not in ("sqlite3", "mcap"):
            raise BagCorrupt(str(path), None,
                             f"unsupported rosbag2 storage {self.storage!r} "
                             "(expected sqlite3 or mcap)")
        self.size = sum(f.stat().st_size for f in self.files if f.exists())
        self.bytes_read = 0

    def scan(self) -> Iterator[Item]:
        if self.storage == "mcap":
            done = 0
            for file in self.files:
                scanner = McapScanner(file)
                try:
                    yield from scanner.scan()
                finally:
                    self.bytes_read = done + scanner.bytes_read
                done += scanner.size
            return
        yield from self._sqlite()

    def _sqlite(self) -> Iterator[Item]:
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.rosbag2 import Reader

        last = None
        try:
            with Reader(self.path) as reader:
                topics = {}
                for conn in reader.connections:
                    fmt = ("idl" if conn.msgdef.format == MessageDefinitionFormat.IDL
                           else "msg")
                    topic = RecordedTopic(conn.topic, conn.msgtype, "cdr",
                                          conn.msgdef.data, fmt, conn.digest)
                    topics[conn.id] = topic
                    yield topic
                for conn, stamp, data in reader.messages():
                    last = stamp
                    yield RecordedMessage(stamp, topics[conn.id], data)
        except (sqlite3.Error, OSError, ValueError, KeyError) as exc:
            after = f" after the message recorded at {last / 1e9:.9f} s" if last else ""
            raise BagCorrupt(str(self.path), None, f"{exc}{after}") from None
        except Exception as exc:
            if type(exc).__module__.startswith("rosbags"):
                raise BagCorrupt(str(self.path), None, str(exc)) from None
            raise
        self.bytes_read = self.size
