"""The station's status history (``station/status_history.py``) on real SQLite files: what
the timeline draws DEGRADED and UNKNOWN spans from.

A row is kept each time an entity's status changes, at the robot's time, in the same
transaction as the status; the robot's own row is its derived status (the badge's rule);
an older database (schema version 1) gains the table when opened.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.health.ids import robot_resource_id
from blackbox.station.status_history import ROBOT
from blackbox.station.store import SCHEMA_VERSION, StationStore

T0 = 1_800_000_000.0


@pytest.fixture
def store(tmp_path: Path) -> Iterator[StationStore]:
    s = StationStore.open(tmp_path / "station.db", clock=lambda: T0 + 1000)
    yield s
    s.close()


def test_a_status_is_kept_when_it_changes_and_the_robot_by_its_badges_rule(
        store: StationStore) -> None:
    rid = robot_resource_id("bot")
    store.heard(rid, T0)
    store.put_robot_id(rid, "bot")
    store.put_entity(rid, 1, name="bot", kind="robot", status="OPERATIONAL", updated=T0)
    store.put_entity(rid, 2, name="/cam", kind="node", status="OPERATIONAL", updated=T0)
    for second in range(1, 6):  # the same status, sample after sample: nothing new kept
        store.put_entity(rid, 2, status="OPERATIONAL", updated=T0 + second)
    store.put_entity(rid, 2, status="DEGRADED", updated=T0 + 10)
    store.put_entity(rid, 2, status="NOT_OPERATIONAL", updated=T0 + 20)
    store.put_entity(rid, 1, status="NOT_OPERATIONAL", updated=T0 + 25)
    store.put_entity(rid, 2, name="/cam", updated=T0 + 26)  # no status: nothing kept
    assert store.flush(force=True)

    track = store.status_track("bot", T0, T0 + 100)
    assert track.before == {}
    assert [(t - T0, iid, status) for t, iid, status in track.changes] == [
        (0, 1, "OPERATIONAL"), (0, ROBOT, "OPERATIONAL"), (0, 2, "OPERATIONAL"),
        (10, 2, "DEGRADED"), (10, ROBOT, "DEGRADED"),  # a mix: DEGRADED, as the badge
        (20, 2, "NOT_OPERATIONAL"),  # robot OPERATIONAL + node down: still DEGRADED
        (25, 1, "NOT_OPERATIONAL"), (25, ROBOT, "NOT_OPERATIONAL")]
    assert store.robot("bot", now=T0 + 1).status == "NOT_OPERATIONAL"  # heard, not stale

    later = store.status_track("bot", T0 + 15, T0 + 100)  # what each had at the start
    assert later.before == {1: "OPERATIONAL", 2: "DEGRADED", ROBOT: "DEGRADED"}
    assert [(t - T0, iid) for t, iid, _ in later.changes] == [(20, 2), (25, 1), (25, ROBOT)]
    assert later.known() == {1, 2, ROBOT}


def test_an_older_database_gains_the_history_when_opened(tmp_path: Path) -> None:
    path = tmp_path / "station.db"
    StationStore.open(path).close()
    db = sqlite3.connect(path)  # as version 2 left it: no status_changes table
    db.execute("DROP TABLE status_changes")
    db.execute("UPDATE meta SET value = '2' WHERE key = 'schema_version'")
    db.commit()
    db.close()
    store = StationStore.open(path, clock=lambda: T0)
    try:
        rid = robot_resource_id("bot")
        store.heard(rid, T0)
        store.put_entity(rid, 2, name="/cam", kind="node", status="DEGRADED", updated=T0)
        assert store.flush(force=True)
        assert [s for _, _, s in store.status_track("bot", T0 - 1, T0 + 1).changes] == \
            ["DEGRADED", "DEGRADED"]
    finally:
        store.close()
    db = sqlite3.connect(path)
    assert db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0] \
        == str(SCHEMA_VERSION) == "3"
    db.close()


def test_the_robots_status_derived_in_sql_is_the_badges_rule() -> None:
    """The store keeps a robot's status history with ROBOT_STATUS_SQL (no read back);
    it must give what robot_status gives the badge, for every mix of entity statuses."""
    import itertools
    import sqlite3

    from blackbox.station.status import ROBOT_STATUS_SQL, robot_status

    db = sqlite3.connect(":memory:")
    db.execute("CREATE TABLE entities (resource_id INTEGER, instance_id INTEGER, status TEXT)")
    names = ("OPERATIONAL", "DEGRADED", "NOT_OPERATIONAL", "UNKNOWN")
    checked = 0
    for size in range(4):
        for statuses in itertools.combinations_with_replacement(names, size):
            db.execute("DELETE FROM entities")
            db.executemany("INSERT INTO entities VALUES (1, ?, ?)", enumerate(statuses))
            derived = db.execute(ROBOT_STATUS_SQL, (1,)).fetchone()[0]
            assert derived == robot_status(statuses, stale=False, online=True), statuses
            checked += 1
    assert checked == 35
