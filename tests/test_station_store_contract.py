"""The station store's contract, held against every backend: SQLite and PostgreSQL.

Each test names one behaviour of the protocols in ``blackbox.station.protocols`` and runs
on an SQLite file and on a database of a real PostgreSQL cluster (``postgres_support``).
A backend that passes these can stand behind the station's pages, API and follower.
"""

from __future__ import annotations

import io
import json
import math
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.ids import robot_resource_id
from blackbox.record.store import LogEntry
from blackbox.station.auth import Auth, Role
from blackbox.station.changes import Change
from blackbox.station.database import open_database
from blackbox.station.enrolment import RobotKeys
from blackbox.station.records import Point, StationStoreError, UnknownRobot
from blackbox.station.store import StationStore
from blackbox.station.tokens import ApiTokens
from conftest import wait_until
from postgres_support import postgres, postgres_url  # noqa: F401  (fixtures)

T0 = 1_800_000_000.0
RID = robot_resource_id("tug-1")
BACKENDS = ["sqlite", "postgresql"]


class Clock:
    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(params=BACKENDS)
def location(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "sqlite":
        return str(tmp_path / "station.db")
    url: str = request.getfixturevalue("postgres_url")
    return url


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def store(location: str, clock: Clock) -> Iterator[StationStore]:
    s = StationStore(location, clock=clock, stale_after=10.0)
    yield s
    s.close()


def robot_with_a_failing_camera(store: StationStore) -> None:
    store.put_robot_id(RID, "tug-1")
    store.heard(RID, T0)
    store.put_entity(RID, 1, name="tug-1", kind="robot", status="DEGRADED")
    store.put_entity(RID, 2, name="/camera", kind="node", status="NOT_OPERATIONAL",
                     parent=1, cause="no frames", actions="restart the driver",
                     characteristics=[10])
    store.put_entity(RID, 3, name="/lidar", kind="node", status="OPERATIONAL", parent=1)
    store.put_characteristic(RID, 10, entity=2, name="frame rate", observer="rate",
                             resource="/camera/image", quantity="rate", unit="Hz",
                             expected_noise=0.5, exceeded=True)
    store.put_threshold(RID, 11, 10, "too slow", "min", 10.0)
    store.put_diagnosis(RID, ["/camera"], T0 - 1)
    assert store.flush()


def test_a_robot_heard_is_in_the_fleet_with_its_status_and_counts(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    [summary] = store.fleet()
    assert (summary.robot_id, summary.resource_id, summary.status) == ("tug-1", RID,
                                                                         "DEGRADED")
    assert (summary.entities, summary.failing, summary.diagnosis) == (3, 1, ("/camera",))
    assert store.robot("tug-1").resource_id == RID == store.resource_of(f"#{RID}")
    assert store.robot_id_of(RID) == "tug-1" and store.robot_id_of(1) == "#1"
    assert store.last_heard("tug-1") == T0


def test_later_hearings_only_move_last_heard_forward(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    store.heard(RID, T0 + 5)
    store.heard(RID, T0 + 2)
    assert store.flush()
    assert store.last_heard(RID) == T0 + 5


def test_a_silent_robot_is_unknown_and_an_unknown_robot_is_refused(
        store: StationStore, clock: Clock) -> None:
    robot_with_a_failing_camera(store)
    clock.now = T0 + 60
    assert store.robot(RID).status == "UNKNOWN" and store.robot(RID).stale
    store.put_robot_online(RID, False)
    assert store.flush()
    assert not store.robot(RID).online
    with pytest.raises(UnknownRobot):
        store.robot("nobody")
    assert store.last_heard("nobody") is None and store.last_event_time("nobody") is None


def test_entities_form_a_tree_robot_first_and_keep_unsent_fields(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    store.put_entity(RID, 2, failures=3)  # only the count: the rest stays
    assert store.flush()
    tree = store.entities(RID)
    assert [e.name for e in tree] == ["tug-1", "/camera", "/lidar"]
    camera = store.entity_by_name(RID, "/camera")
    assert camera is not None and camera == store.entity(RID, 2)
    assert (camera.parent, camera.status, camera.failures, camera.characteristics) == (
        1, "NOT_OPERATIONAL", 3, 1)
    assert store.entity(RID, 99) is None


def test_the_diagnosis_is_explained_with_causes_and_actions(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    d = store.diagnosis("tug-1")
    assert d.components == ("/camera",) and d.since == T0 - 1
    assert "/camera" in d.explanation and "restart the driver" in d.explanation
    assert d.causes == {"/camera": "no frames"}


def test_characteristics_carry_thresholds_and_values_make_a_thinned_series(
        store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    for i in range(100):
        store.put_value(RID, 10, T0 - 100 + i, float(i), entity=2)
    store.put_value(RID, 10, T0 - 500, -1.0)  # older than the current value: chart only
    store.put_threshold(RID, 11, 10, "too slow", "min", 12.0)  # replaced, not added
    assert store.flush()
    [c] = store.characteristics(RID)
    assert (c.name, c.unit, c.value, c.time, c.exceeded) == ("frame rate", "Hz", 99.0,
                                                             T0 - 1, True)
    assert [(t.name, t.type, t.value) for t in c.thresholds] == [("too slow", "min", 12.0)]
    assert store.characteristics(RID, entity=3) == []
    full = store.series(RID, 10, since=T0 - 1000)
    assert len(full) == 101 and full[0].value == -1.0 and full[-1].value == 99.0
    thinned = store.series(RID, 10, since=T0 - 1000, max_points=10)
    assert 1 < len(thinned) <= 11 and thinned == sorted(thinned, key=lambda p: p.time)


def test_an_event_is_stored_once_per_identity(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    for _ in range(3):
        store.add_event(RID, T0, "failure", dedup="id:boot-1", entity="/camera",
                        text="camera silent", details={"seq": 1})
    store.add_event(RID, T0, "failure", dedup="id:boot-2", entity="/camera")
    store.add_event(RID, T0, "exceedance", dedup="id:boot-3", origin="log",
                    characteristic="frame rate")
    assert store.flush()
    assert store.count_events() == 3
    assert store.count_events(RID, kinds=["failure"]) == 2
    assert store.count_events(origin="log") == 1
    assert store.last_event_time(RID) == T0
    first = store.events_after(0, limit=1)[0]
    assert first.details == {"seq": 1} and store.event(first.id) == first
    assert store.last_event_id() == max(e.id for e in store.events_after(0))
    with pytest.raises(ValueError):
        store.add_event(RID, T0, "gossip", dedup="x")


def test_an_event_named_late_is_rekeyed_or_merged_with_its_logged_copy(
        store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    store.add_event(RID, T0, "failure", dedup="failure|t0|/camera", entity="/camera")
    store.add_event(RID, T0 + 1, "exceedance", dedup="exceedance|t1|rate", text="slow")
    store.add_event(RID, T0 + 1, "exceedance", dedup="id:b-2", origin="log", text="slow")
    assert store.flush()
    [unnamed] = store.events(kinds=["failure"]).events
    [time_keyed] = [e for e in store.events(kinds=["exceedance"]).events if e.origin == "live"]
    store.acknowledge(time_keyed.id, "olga")
    # The failure's identity: its row is re-keyed, the same row.
    store.name_event(RID, "failure|t0|/camera", T0, "failure", dedup="id:b-1",
                     entity="/camera", text="silent", details={"event_id": "b-1"})
    # The exceedance's identity: its logged copy is stored already, the two become one.
    store.name_event(RID, "exceedance|t1|rate", T0 + 1, "state_change", dedup="id:b-2",
                     text="slow (state ok -> fast)")
    # Two events of one millisecond had shared the failure's time key: the second is added.
    store.name_event(RID, "failure|t0|/camera", T0, "failure", dedup="id:b-3",
                     entity="/camera", text="silent again")
    assert store.flush()
    failures = store.events(kinds=["failure"]).events
    assert {e.text for e in failures} == {"silent", "silent again"}
    assert [e.details for e in failures if e.id == unnamed.id] == [{"event_id": "b-1"}]
    [kept] = store.events(kinds=["exceedance"]).events
    assert (kept.origin, kept.acknowledged_by) == ("log", "olga")
    [ack] = store.events(kinds=["acknowledgement"]).events
    assert ack.refers_to == kept.id
    assert store.count_events() == 4


def test_events_stored_under_an_entitys_id_take_its_name_once_it_is_described(
        store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    other = robot_resource_id("tug-2")
    said = "#4 is no longer diagnosed faulty"
    store.add_event(RID, T0, "rectification", dedup="rectification|t0|#4", entity="#4",
                    text=said)
    store.add_event(RID, T0, "failure", dedup="failure|t0|#4", entity="#4", text="no fix")
    store.add_event(RID, T0, "failure", dedup="failure|t0|#5", entity="#5", text=said)
    store.add_event(other, T0, "rectification", dedup="rectification|t0|#4", entity="#4",
                    text=said)
    store.name_entity_events(RID, "#4", "/gps", {said: "/gps is no longer diagnosed faulty"})
    assert store.flush()
    named = sorted((e.kind, e.entity, e.text) for e in store.events(RID).events)
    assert named == [("failure", "#5", said), ("failure", "/gps", "no fix"),
                     ("rectification", "/gps", "/gps is no longer diagnosed faulty")]
    [untouched] = store.events(other).events
    assert (untouched.entity, untouched.text) == ("#4", said)


def test_events_page_newest_first_with_filters_and_a_cursor(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    for i in range(25):
        store.add_event(RID, T0 + i, "failure" if i % 2 else "exceedance",
                        dedup=f"id:b-{i}", entity="/camera" if i < 20 else "/lidar")
    assert store.flush()
    page = store.events(RID, limit=10)
    assert [e.time for e in page.events] == [T0 + i for i in range(24, 14, -1)]
    rest = store.events(RID, limit=100, cursor=page.next_cursor)
    assert len(rest.events) == 15 and rest.next_cursor is None
    assert {e.entity for e in store.events(entity="/lidar").events} == {"/lidar"}
    assert len(store.events(kinds=["failure"], since=T0 + 10, until=T0 + 19).events) == 5
    assert store.events("nobody").events == ()
    with pytest.raises(ValueError):
        store.events(cursor="garbage")


def test_acknowledging_marks_the_event_once_and_adds_an_acknowledgement(
        store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    store.add_event(RID, T0, "failure", dedup="id:b-1", entity="/camera", text="silent")
    assert store.flush()
    [event] = store.events(unacknowledged=True).events
    acked = store.acknowledge(event.id, "olga", "on it")
    assert acked.acknowledged_by == "olga"
    assert store.acknowledge(event.id, "bert").acknowledged_by == "olga"
    assert store.events(unacknowledged=True).events == ()
    [ack] = store.events(kinds=["acknowledgement"]).events
    assert ack.refers_to == event.id and "on it" in ack.text
    assert store.fleet()[0].unacknowledged == 0
    with pytest.raises(LookupError):
        store.acknowledge(999_999, "olga")


def test_a_log_request_keeps_its_rows_in_order_and_exports_them(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    req = store.create_log_request(RID, "tug-1", entity="/camera", characteristic=None,
                                   since=T0 - 60, until=T0, kinds=["failure"],
                                   requested_by="olga")
    entries = [LogEntry(100 + i, T0 - 60 + i, "failure", "/camera", None, None, {"i": i})
               for i in range(30)]
    store.add_log_rows(req, 0, entries[:20])
    store.add_log_rows(req, 10, entries[10:30])  # overlapping page: stored once
    store.update_log_request(req, RID, status="done", rows=30, pages=2, progress=1.0,
                             finished=T0)
    assert store.flush()
    info = store.log_request(req)
    assert info is not None and (info.status, info.rows, info.kinds) == ("done", 30,
                                                                         ("failure",))
    assert [r.id for r in store.log_requests("tug-1")] == [req]
    assert [e.id for e in store.log_entries(req, 5, 3)] == [105, 106, 107]
    assert [e.payload["i"] for e in store.iter_log_entries(req, batch=7)] == list(range(30))
    out = io.StringIO()
    assert store.export_log(req, "jsonl", out) == 30
    assert json.loads(out.getvalue().splitlines()[0])["id"] == 100
    assert store.log_request(req + 1000) is None


def test_an_ibit_run_is_created_then_finished(store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    run = store.create_ibit_run(RID, "tug-1", "/camera", "olga")
    assert store.ibit_run(run) is not None and store.ibit_run(run).status == "pending"  # type: ignore[union-attr]
    store.finish_ibit_run(run, RID, status="done", health="NOT_OPERATIONAL",
                          observations=4, failed=1, report=["frame rate 0 Hz"])
    assert store.flush()
    [done] = store.ibit_runs(RID)
    assert (done.id, done.status, done.failed, done.report) == (run, "done", 1,
                                                                ("frame rate 0 Hz",))


def test_each_commit_is_announced_to_subscribers_and_listeners(store: StationStore) -> None:
    seen: list[Change] = []
    remove = store.add_listener(seen.append)
    with store.subscribe() as sub:
        before = store.sequence
        robot_with_a_failing_camera(store)
        change = sub.get(timeout=5)
        assert change is not None and RID in change.robots and "fleet" in change.topics
        assert store.wait_for_change(before, 5) > before
    remove()
    assert seen and seen[0].seq == change.seq


def test_problems_are_counted_and_cleared(store: StationStore) -> None:
    store.report_problem("robot", "id reused")
    store.report_problem("robot", "id reused")
    [p] = store.problems()
    assert (p.source, p.count) == ("robot", 2)
    store.clear_problem("robot")
    assert store.problems() == []


def test_a_second_store_on_the_same_database_sees_what_the_first_wrote(
        location: str, clock: Clock, store: StationStore) -> None:
    robot_with_a_failing_camera(store)
    store.add_event(RID, T0, "failure", dedup="id:b-1", entity="/camera")
    assert store.flush()
    other = StationStore(location, clock=clock)
    try:
        other.add_event(RID, T0, "failure", dedup="id:b-1", entity="/camera")  # same event
        other.add_event(RID, T0, "failure", dedup="id:b-2", entity="/camera")
        assert other.flush()
        assert other.fleet()[0].robot_id == "tug-1"
        assert store.count_events() == other.count_events() == 2
    finally:
        other.close()


def test_accounts_tokens_and_robot_keys_live_in_the_same_database(location: str,
                                                                  store: StationStore) -> None:
    from argon2 import PasswordHasher

    quick = PasswordHasher(time_cost=1, memory_cost=1024, parallelism=1)
    auth = Auth(location, hasher=quick)
    other = Auth(location, hasher=quick)
    tokens = ApiTokens(location, auth)
    keys = RobotKeys(location)
    try:
        auth.add_user("olga", "correct horse battery staple 42", Role.ADMIN)
        login = auth.log_in("olga", "correct horse battery staple 42", "127.0.0.1")
        assert login.session_token is not None
        session = other.session(login.session_token)  # another process, same sessions
        assert session is not None and session.user.name == "olga"
        assert other.log_in("olga", "wrong", "10.0.0.1").session is None
        assert [e.action for e in other.audit_log(user="olga")][:2] == ["login", "login"]
        token, _ = tokens.create("olga", "script", 1)
        user = ApiTokens(location, other).user_of(token)
        assert user is not None and user.name == "olga"
        keys.enrol("tug-1", "A" * 43 + "=")
        assert [r.robot_id for r in RobotKeys(location).robots()] == ["tug-1"]
    finally:
        keys.close()
        tokens.close()
        other.close()
        auth.close()


def test_a_database_that_is_not_a_station_database_is_refused(location: str) -> None:
    database = open_database(location)
    db = database.connect()
    db.execute("CREATE TABLE payroll (name TEXT)")
    db.close()
    with pytest.raises(StationStoreError, match="not a station database"):
        StationStore(location)


def test_status_changes_are_kept_once_each_and_read_by_window(store: StationStore,
                                                              clock: Clock) -> None:
    store.put_robot_id(RID, "tug-1")
    store.heard(RID, T0)
    store.put_entity(RID, 2, name="/camera", kind="node", status="OPERATIONAL", updated=T0)
    store.put_entity(RID, 2, status="OPERATIONAL", updated=T0 + 1)
    store.put_entity(RID, 2, status="DEGRADED", updated=T0 + 5)
    store.put_entity(RID, 2, status="NOT_OPERATIONAL", updated=T0 + 9)
    assert store.flush()
    track = store.status_track("tug-1", T0 + 4, T0 + 20)
    assert track.before[2] == "OPERATIONAL"
    assert [(t - T0, iid, s) for t, iid, s in track.changes if iid == 2] == [
        (5, 2, "DEGRADED"), (9, 2, "NOT_OPERATIONAL")]


def test_writes_wait_in_a_bounded_queue_until_a_flush(location: str, clock: Clock) -> None:
    store = StationStore(location, clock=clock, max_pending=20)
    try:
        robot_with_a_failing_camera(store)
        assert store.pending == 0
        for i in range(30):  # chart points beyond the bound go first: coalesced, counted
            store.put_value(RID, 10, T0 + i, float(i))
        store.add_event(RID, T0, "failure", dedup="id:b-1")
        assert 0 < store.pending <= 20 and store.coalesced_points > 0
        assert any("coalesced" in p.message for p in store.problems())
        assert store.count_events() == 0  # queued, not yet written
        assert store.flush() and store.pending == 0
        assert store.count_events() == 1
        points = store.series(RID, 10, since=T0 - 1)
        assert points[-1] == Point(T0 + 29, 29.0)  # the newest point wins
        assert len(points) + store.coalesced_points + store.dropped_points == 30
    finally:
        store.close()


class TableLock:
    """Another client holding the samples table, so that the store's next flush waits on
    the database (as it does on a slow or loaded server) until :meth:`release`."""

    def __init__(self, location: str) -> None:
        self.postgres = location.startswith("postgresql")
        if self.postgres:
            import psycopg

            self.db: Any = psycopg.connect(location, autocommit=True)
            self.db.execute("BEGIN")
            self.db.execute("LOCK TABLE samples IN EXCLUSIVE MODE")
        else:
            self.db = sqlite3.connect(location, isolation_level=None)
            self.db.execute("BEGIN IMMEDIATE")

    def release(self) -> None:
        self.db.execute("ROLLBACK")
        self.db.close()


def test_queueing_never_waits_on_a_flush_that_waits_on_the_database(location: str,
                                                                    clock: Clock) -> None:
    store = StationStore(location, clock=clock)
    lock: TableLock | None = None
    try:
        robot_with_a_failing_camera(store)
        store.start_writer()
        lock = TableLock(location)
        store.put_value(RID, 10, T0 + 1, 1.0)
        store.flush_soon()  # the writer takes the queue and waits on the lock
        wait_until(lambda: store.pending == 0, "the writer took the queue")
        started = time.monotonic()
        for i in range(2, 1002):  # meanwhile the follower keeps queueing
            store.put_value(RID, 10, T0 + i, float(i))
        queued_in = time.monotonic() - started
        assert store.pending > 0 and queued_in < 1.0, queued_in
        assert len(store.series(RID, 10, since=T0)) == 0  # nothing committed yet
        lock.release()
        lock = None
        store.flush_soon()
        wait_until(lambda: len(store.series(RID, 10, since=T0, max_points=5000)) == 1001,
                   "all 1,001 values committed once the database let go",
                   timeout=30.0, state=lambda: (store.pending, store.problems()))
        assert store.coalesced_points == store.dropped_points == 0
    finally:
        if lock is not None:
            lock.release()
        store.close()


def test_a_flush_says_how_long_its_changes_waited_to_be_committed(location: str,
                                                                   clock: Clock) -> None:
    store = StationStore(location, clock=clock)
    try:
        store.put_value(RID, 10, T0, 1.0)
        time.sleep(0.2)  # the change waits in the queue: part of its commit lag
        store.put_value(RID, 10, T0 + 1, 2.0)
        assert store.flush()
        times = store.flush_times
        assert times.rows == 3  # two chart points and the newest current value
        assert times.lag >= 0.2 + times.seconds - 0.01 and times.seconds > 0
        assert times.lag_max == times.lag
    finally:
        store.close()


def test_many_rows_of_one_upsert_end_as_they_would_one_by_one(location: str) -> None:
    """A flush sends rows of one statement together (on PostgreSQL as statements of many
    rows); rows repeating a key, older ones after newer, end as applied one by one."""
    db = open_database(location).connect()
    try:
        db.execute("CREATE TABLE latest (k INTEGER PRIMARY KEY, v REAL, tm REAL)")
        rows = [(i % 700, float(i), float(i)) for i in range(2500)]  # keys repeat
        rows += [(k, -1.0, 0.0) for k in range(0, 700, 7)]  # older: changes nothing
        db.executemany("INSERT INTO latest (k, v, tm) VALUES (?, ?, ?) ON CONFLICT (k) DO "
                       "UPDATE SET v = excluded.v, tm = excluded.tm "
                       "WHERE latest.tm <= excluded.tm", rows)
        expected: dict[int, float] = {}
        for k, v, _ in rows:
            if v >= expected.get(k, -math.inf):
                expected[k] = v
        stored = dict(db.execute("SELECT k, v FROM latest").fetchall())
        assert stored == expected and len(stored) == 700
    finally:
        db.close()
