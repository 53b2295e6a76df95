"""The health log file: schema, unique entries, queries, purge, broken files."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from blackbox.model import Code, Observation, Resource
from blackbox.record.logfile import classify
from blackbox.record.store import (
    APPLICATION_ID,
    MIGRATIONS,
    SCHEMA_VERSION,
    Row,
    StorageError,
    Store,
    StoreCorrupt,
)

CAM = ("/usb_cam/image_raw", "hz", '{"topic":"/usb_cam/image_raw"}')
CAM_TIMEOUT = ("/usb_cam/image_raw", "timeout", '{"topic":"/usb_cam/image_raw"}')
NODE = ("/usb_cam", "activated", '{"node":"/usb_cam"}')


def filled(path: Path) -> Store:
    store = Store.open(path)
    store.append([
        Row(10.0, "observation", CAM, 0, {"values": {"period": 0.0667}}),
        Row(11.0, "sample", CAM, 0, {"values": {"period": 0.0668}}),
        Row(12.0, "exceedance", CAM, -2, {"values": {"period": 0.5}}),
        Row(12.0, "exceedance", CAM_TIMEOUT, -4, {}),
        Row(13.0, "observation", NODE, -1, {}),
        Row(14.0, "failure", None, None, {"components": ["/usb_cam"], "category": "detection"}),
    ])
    return store


def test_new_store_is_wal_at_latest_schema(tmp_path: Path) -> None:
    with Store.open(tmp_path / "log.db") as store:
        assert store.schema_version == SCHEMA_VERSION == len(MIGRATIONS)
        assert store.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert store.meta("created") is not None


def test_old_schema_is_migrated_in_place(tmp_path: Path) -> None:
    path = tmp_path / "old.db"
    db = sqlite3.connect(path, isolation_level=None)
    MIGRATIONS[0](db)
    db.execute("PRAGMA user_version = 1")
    db.execute("INSERT INTO entries (time, kind, channel, code, payload) "
               "VALUES (5.0, 31, NULL, NULL, '{\"event\":\"start\"}')")
    db.close()
    assert classify(path) == "health_log"  # a log from before the application id
    with Store.open(path) as store:
        assert store.schema_version == SCHEMA_VERSION == 4
        assert store.snapshot_files() == []
        assert store.execute("PRAGMA application_id").fetchone()[0] == APPLICATION_ID
        indexes = {r[0] for r in store.execute("SELECT name FROM sqlite_master WHERE type='index'")}
        assert {"entries_kind_time", "frames_time", "frames_channel_time"} <= indexes
        (entry,) = store.query()
        assert (entry.id, entry.time, entry.kind, entry.payload) == \
            (1, 5.0, "blackbox_event", {"event": "start"})
        # New entries, framed observations too, continue the old log's id sequence.
        r = Resource(topic="/a")
        obs = [Observation(6.0 + i, "hz", r, Code.GENERAL_OK, values={"i": i}) for i in range(9)]
        ids = store.append([(o.time, "sample", ("/a", "hz", "{}"), 0, o) for o in obs])
        assert ids == list(range(2, 11))
        assert store.execute("SELECT count(*) FROM frames").fetchone()[0] == 1
        assert [e.id for e in store.query()] == list(range(1, 11))


def test_newer_schema_is_refused_with_a_clear_message(tmp_path: Path) -> None:
    path = tmp_path / "new.db"
    Store.open(path).close()
    db = sqlite3.connect(path)
    db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    db.close()
    with pytest.raises(StorageError, match="written by a newer blackbox"):
        Store.open(path)


def test_entries_have_unique_increasing_ids_even_after_purge(tmp_path: Path) -> None:
    store = filled(tmp_path / "log.db")
    ids = [e.id for e in store.query()]
    assert ids == [1, 2, 3, 4, 5, 6]
    store.purge(20.0)
    (new,) = store.append([Row(21.0, "sample", CAM, 0, {})])
    assert new == 8  # 7 is the purge record; numbers are never reused
    store.close()


def test_query_filters_by_entity_characteristic_time_and_kind(tmp_path: Path) -> None:
    store = filled(tmp_path / "log.db")
    assert [e.id for e in store.query(entity="/usb_cam/image_raw")] == [1, 2, 3, 4]
    assert [e.id for e in store.query(entity="/usb_cam/image_raw", characteristic="hz")] == \
        [1, 2, 3]
    assert [e.id for e in store.query(entity="/usb_cam*")] == [1, 2, 3, 4, 5]
    assert [e.id for e in store.query(start=11.0, end=12.0)] == [2, 3, 4]
    assert [e.id for e in store.query(kinds=["exceedance", "failure"])] == [3, 4, 6]
    assert [e.id for e in store.query(limit=2)] == [1, 2]
    failure = next(store.query(kinds=["failure"]))
    assert failure.to_dict() == {"id": 6, "time": 14.0, "kind": "failure", "entity": None,
                                 "characteristic": None, "code": None,
                                 "payload": {"components": ["/usb_cam"],
                                             "category": "detection"}}
    with pytest.raises(ValueError, match="unknown kind 'failures'"):
        list(store.query(kinds=["failures"]))
    store.close()


def test_readonly_reader_sees_committed_entries_while_writer_is_open(tmp_path: Path) -> None:
    writer = filled(tmp_path / "log.db")
    with Store.open(tmp_path / "log.db", readonly=True) as reader:
        assert reader.count() == 6
        writer.append([Row(15.0, "sample", CAM, 0, {})])
        assert reader.count() == 7
        with pytest.raises(sqlite3.OperationalError):
            reader.execute("DELETE FROM entries")
    writer.close()


def test_purge_empties_keeps_latest_configuration_and_records_itself(tmp_path: Path) -> None:
    store = filled(tmp_path / "log.db")
    store.append([Row(1.0, "config", None, None, {"text": "a", "version": None}),
                  Row(2.0, "config", None, None, {"text": "b", "version": None})])
    entry = store.purge(30.0, by="maintenance")
    kept = [(e.kind, e.payload.get("text"), e.payload.get("version")) for e in store.query()]
    assert kept == [("config", "b", 2), ("blackbox_event", None, None)]
    assert entry.payload == {"event": "purge", "deleted": 7, "by": "maintenance",
                             "kept_config_entry": 8}
    store.close()


def test_configuration_versions_count_up(tmp_path: Path) -> None:
    with Store.open(tmp_path / "log.db") as store:
        rows = [Row(float(i), "config", None, None, {"text": str(i), "version": None})
                for i in range(3)]
        store.append(rows[:1])
        store.append(rows[1:])
        assert [e.payload["version"] for e in store.query(kinds=["config"])] == [1, 2, 3]


def test_garbage_file_is_reported_corrupt(tmp_path: Path) -> None:
    path = tmp_path / "log.db"
    path.write_bytes(b"this is not a database at all" * 200)
    with pytest.raises(StoreCorrupt, match="not a healthy health log"):
        Store.open(path)


def test_foreign_database_is_not_mistaken_for_a_log(tmp_path: Path) -> None:
    path = tmp_path / "other.db"
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE t (x)")
    db.commit()
    db.close()
    with pytest.raises(StoreCorrupt, match="not a health log"):
        Store.open(path)


def test_reading_a_missing_log_says_so(tmp_path: Path) -> None:
    with pytest.raises(StorageError, match="no such health log"):
        Store.open(tmp_path / "missing.db", readonly=True)


def test_non_finite_values_survive_as_text(tmp_path: Path) -> None:
    with Store.open(tmp_path / "log.db") as store:
        store.append([Row(1.0, "sample", CAM, 0, {"values": {"period": float("inf")}})])
        assert next(store.query()).payload == {"values": {"period": "inf"}}
