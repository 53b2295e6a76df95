"""The station's writes in batches on real SQLite files: entity statuses
(``station/status_batch.py``), and one row per flush for a robot's last-heard time and a
characteristic's current value. The status history, the robots, the characteristics and
the change feed are what one write per sample gave, whatever lands in one flush, and a
flush that rolled back makes the store believe nothing it read in it."""

from __future__ import annotations

import random
import sqlite3
from pathlib import Path
from typing import Any

from blackbox.health.ids import robot_resource_id
from blackbox.station.status_batch import KeptStatuses
from blackbox.station.status_history import ROBOT
from blackbox.station.store import StationStore

T0 = 1_800_000_000.0
STATUSES = ("OPERATIONAL", "DEGRADED", "NOT_OPERATIONAL", "UNKNOWN")
ROBOTS = ("bot-a", "bot-b", "bot-c")


def _feed(store: StationStore, seed: int, flush_every: int | None) -> None:
    """The same random stream of entity samples (mostly unchanged statuses), values and
    descriptions, flushed after every write (``None``) or at random points."""
    rng, flushes = random.Random(seed), random.Random(seed + 1)
    status = {(r, e): "OPERATIONAL" for r in ROBOTS for e in (1, 2, 3)}
    for robot in ROBOTS:
        rid = robot_resource_id(robot)
        store.heard(rid, T0)
        store.put_robot_id(rid, robot)
    for step in range(600):
        robot, entity = rng.choice(ROBOTS), rng.choice((1, 2, 3))
        rid, t = robot_resource_id(robot), T0 + step
        if rng.random() < 0.1:
            status[robot, entity] = rng.choice(STATUSES)
        store.heard(rid, t + rng.uniform(-3, 3))  # arrival times out of order too
        store.put_entity(rid, entity, status=status[robot, entity], online=True,
                         updated=t, kind="robot" if entity == 1 else "node")
        if entity == 1:
            store.put_robot_online(rid, rng.random() < 0.9)
        store.put_value(rid, 10 + entity, t + rng.choice((-2.0, 0.0, 0.0, 1.5)), rng.random())
        if rng.random() < 0.05:
            store.put_entity(rid, entity, name=f"/e{entity}")  # a description: a row
        if flush_every is None or flushes.randrange(flush_every) == 0:
            assert store.flush(force=True)
    assert store.flush(force=True)


def _history(store: StationStore, robots: tuple[str, ...] = ROBOTS
             ) -> dict[str, list[tuple[float, int, str]]]:
    return {r: list(store.status_track(r, T0 - 1, T0 + 10_000).changes) for r in robots}


def _stored(store: StationStore, path: Path) -> dict[str, Any]:
    """Every robot's row and every characteristic's current value and chart points."""
    db = sqlite3.connect(path)
    out: dict[str, Any] = {"robots": db.execute(
        "SELECT resource_id, first_heard, last_heard, online FROM robots "
        "ORDER BY resource_id").fetchall()}
    db.close()
    for robot in ROBOTS:
        out[robot] = ([(c.instance_id, c.value, c.time) for c in store.characteristics(robot)],
                      {iid: store.series(robot, iid, T0 - 10, T0 + 10_000)
                       for iid in (11, 12, 13)})
    return out


def test_writes_in_batches_keep_what_one_write_at_a_time_kept(tmp_path: Path) -> None:
    # chart points kept for longer than the stream's times (nothing pruned meanwhile)
    one_by_one = StationStore.open(tmp_path / "single.db", clock=lambda: T0 + 5000,
                                   series_retention=1e6)
    batched = StationStore.open(tmp_path / "batched.db", clock=lambda: T0 + 5000,
                                series_retention=1e6)
    try:
        _feed(one_by_one, seed=7, flush_every=None)
        _feed(batched, seed=7, flush_every=40)
        expected = _history(one_by_one)
        assert _history(batched) == expected
        assert sum(1 for changes in expected.values() for _, iid, _ in changes
                   if iid == ROBOT) > 3, "the stream changed no robot's status"
        assert [(r.name, r.status, r.online, r.last_heard)
                for r in batched.fleet(now=T0 + 600)] == \
            [(r.name, r.status, r.online, r.last_heard) for r in one_by_one.fleet(now=T0 + 600)]
        assert _stored(batched, tmp_path / "batched.db") == \
            _stored(one_by_one, tmp_path / "single.db")
    finally:
        one_by_one.close()
        batched.close()


def test_every_robot_of_a_batch_is_in_the_change_it_committed(tmp_path: Path) -> None:
    store = StationStore.open(tmp_path / "station.db", clock=lambda: T0)
    try:
        rids = [robot_resource_id(r) for r in ROBOTS]
        for rid in rids:
            store.heard(rid, T0)
        assert store.flush(force=True)
        with store.subscribe() as changes:
            for rid in rids:  # one batch: nothing but rows queued in between
                store.heard(rid, T0 + 1)
                store.put_entity(rid, 2, status="DEGRADED", updated=T0 + 1)
            assert store.flush(force=True)
            change = changes.get(timeout=5)
        assert change is not None
        assert change.robots == frozenset(rids)
        assert "entities" in change.topics
    finally:
        store.close()


def test_a_rolled_back_flush_is_applied_again_in_full(tmp_path: Path) -> None:
    """The status change is read, kept and then rolled back with the rest of its flush
    (another change in it failed): the retry keeps it again; nothing of the failed
    transaction is believed."""
    path = tmp_path / "station.db"
    store = StationStore.open(path, clock=lambda: T0 + 100)
    rid = robot_resource_id("bot-a")
    try:
        store.heard(rid, T0)
        store.put_robot_id(rid, "bot-a")
        store.put_entity(rid, 2, kind="node", status="OPERATIONAL", updated=T0)
        assert store.flush(force=True)
        other = sqlite3.connect(path)
        events_sql = [sql for (sql,) in other.execute(
            "SELECT sql FROM sqlite_master WHERE tbl_name = 'events' AND sql IS NOT NULL")]
        other.execute("DROP TABLE events")
        other.commit()

        store.put_entity(rid, 2, status="DEGRADED", updated=T0 + 10)
        store.add_event(rid, T0 + 10, "failure", dedup="f1", entity="/cam", text="down")
        assert not store.flush(force=True), "the flush wrote to a table that is not there"
        assert _history(store, ("bot-a",))["bot-a"][-1][2] == "OPERATIONAL"

        for sql in events_sql:
            other.execute(sql)
        other.commit()
        other.close()
        assert store.flush(force=True)
        assert [(t - T0, iid, s) for t, iid, s in _history(store, ("bot-a",))["bot-a"]][-2:] == [
            (10, 2, "DEGRADED"), (10, ROBOT, "DEGRADED")]
    finally:
        store.close()


def test_a_kept_status_is_read_again_after_a_while() -> None:
    """Another station process on the same database may have kept a newer status: what
    this one knows is believed for ``recheck`` seconds only, and only once committed."""
    now = [0.0]
    kept = KeptStatuses(recheck=10.0, clock=lambda: now[0])
    kept.stage((1, 2), "DEGRADED")
    assert kept.kept((1, 2), "DEGRADED")  # within its own transaction
    kept.discard()
    assert not kept.kept((1, 2), "DEGRADED")
    kept.stage((1, 2), "DEGRADED")
    kept.commit()
    now[0] = 9.9
    assert kept.kept((1, 2), "DEGRADED") and not kept.kept((1, 2), "OPERATIONAL")
    now[0] = 10.0
    assert not kept.kept((1, 2), "DEGRADED")
    kept.load({(1, 3): "OPERATIONAL"})  # what a starting store reads at once
    assert kept.kept((1, 3), "OPERATIONAL") and not kept.kept((1, 3), "DEGRADED")
