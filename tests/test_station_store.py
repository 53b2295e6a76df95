"""The station database (``blackbox.station.store``) on real SQLite files: what the web
reads, how it survives a restart and a full disk, and how it tells about changes."""

from __future__ import annotations

import io
import json
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.health.ids import robot_resource_id
from blackbox.record.export import read_jsonl
from blackbox.record.store import LogEntry
from blackbox.station.store import (
    SCHEMA_VERSION,
    StationStore,
    StationStoreError,
    UnknownRobot,
)
from station_support import FULL_DISK_VARIANTS, FullDisk, full_disk_in

T0 = 1_800_000_000.0


class Clock:
    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> float:
        return self.now


def robot(store: StationStore, name: str, statuses: dict[str, str], t: float = T0) -> int:
    """A robot ``name`` with a robot entity and one node per ``statuses`` entry."""
    rid = robot_resource_id(name)
    store.heard(rid, t)
    store.put_robot_id(rid, name)
    store.put_entity(rid, 1, name=name, kind="robot", status="OPERATIONAL", online=True)
    for i, (node, status) in enumerate(sorted(statuses.items()), start=2):
        store.put_entity(rid, i, name=node, kind="node", parent=1, status=status, online=True)
    assert store.flush()
    return rid


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def store(tmp_path: Path, clock: Clock) -> Iterator[StationStore]:
    s = StationStore.open(tmp_path / "station.db", stale_after=10.0, clock=clock)
    yield s
    s.close()


def test_the_database_is_one_sqlite_file_in_wal_mode_with_its_schema_version(
        tmp_path: Path, store: StationStore) -> None:
    robot(store, "alpha", {"/cam": "OPERATIONAL"})
    store.close()
    db = sqlite3.connect(tmp_path / "station.db")
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    meta = dict(db.execute("SELECT key, value FROM meta").fetchall())
    assert meta["application"] == "blackbox-station"
    assert meta["schema_version"] == str(SCHEMA_VERSION)
    db.close()
    again = StationStore.open(tmp_path / "station.db")
    try:
        assert [r.robot_id for r in again.fleet()] == ["alpha"]
    finally:
        again.close()


def test_a_file_that_is_not_a_station_database_is_refused_and_left_alone(tmp_path: Path) -> None:
    other = tmp_path / "health.db"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE entries (x)")
    db.commit()
    db.close()
    before = other.read_bytes()
    with pytest.raises(StationStoreError, match="not a station database"):
        StationStore.open(other)
    assert other.read_bytes() == before
    text = tmp_path / "notes.txt"
    text.write_text("hello\n" * 100)
    with pytest.raises(StationStoreError):
        StationStore.open(text)
    assert text.read_text() == "hello\n" * 100
    with pytest.raises(StationStoreError, match="does not exist"):
        StationStore.open(tmp_path / "missing" / "station.db")


def test_fleet_shows_the_ucms_status_and_a_silent_robot_turns_unknown(
        store: StationStore, clock: Clock) -> None:
    robot(store, "alpha", {"/cam": "NOT_OPERATIONAL", "/audio": "DEGRADED"})
    robot(store, "bravo", {"/cam": "OPERATIONAL"})
    fleet = {r.robot_id: r for r in store.fleet()}
    assert fleet["alpha"].status == "DEGRADED"  # one entity down: the UCMS rule (status.py)
    tree = {e.kind: e.status for e in store.entities("alpha")}
    assert tree["robot"] == fleet["alpha"].status == store.robot("alpha").status
    assert fleet["alpha"].failing == 2
    assert fleet["bravo"].status == "OPERATIONAL"
    assert not fleet["bravo"].stale

    clock.now = T0 + 11  # bravo keeps talking, alpha falls silent
    store.heard(robot_resource_id("bravo"), clock.now)
    store.flush()
    fleet = {r.robot_id: r for r in store.fleet()}
    assert (fleet["alpha"].status, fleet["alpha"].stale) == ("UNKNOWN", True)
    assert fleet["alpha"].reported_status == "OPERATIONAL"
    assert fleet["bravo"].status == "OPERATIONAL"
    tree = store.entities("alpha")
    assert {e.status for e in tree} == {"UNKNOWN"}  # what is shown
    assert {e.name: e.reported_status for e in tree}["/cam"] == "NOT_OPERATIONAL"


def test_a_stopped_black_box_shows_unknown(store: StationStore) -> None:
    rid = robot(store, "alpha", {"/cam": "OPERATIONAL"})
    store.put_robot_online(rid, False)
    store.flush()
    summary = store.robot("alpha")
    assert (summary.status, summary.online) == ("UNKNOWN", False)
    assert "stopped" in store.diagnosis("alpha").explanation


def test_entity_tree_has_the_robot_first_and_parents(store: StationStore) -> None:
    rid = robot(store, "alpha", {"/cam": "OPERATIONAL"})
    store.put_entity(rid, 9, name="iface:eth0", kind="interface", parent=1, status="DEGRADED")
    store.put_entity(rid, 8, name="/scan", kind="topic", parent=1, status="OPERATIONAL")
    store.flush()
    tree = store.entities("alpha")
    assert [(e.name, e.kind, e.parent) for e in tree] == [
        ("alpha", "robot", None), ("/cam", "node", 1), ("/scan", "topic", 1),
        ("iface:eth0", "interface", 1)]
    assert store.entity_by_name(rid, "iface:eth0").status == "DEGRADED"  # type: ignore[union-attr]


def test_robots_are_addressed_by_id_or_resource_id_and_unknown_ones_are_refused(
        store: StationStore) -> None:
    rid = robot(store, "alpha", {})
    assert store.robot("alpha") == store.robot(rid) == store.robot(f"#{rid}")
    with pytest.raises(UnknownRobot):
        store.robot("nobody")
    with pytest.raises(UnknownRobot):
        store.entities(12345)
    assert store.events("nobody").events == ()


def test_diagnosis_explains_in_plain_words(store: StationStore) -> None:
    rid = robot(store, "alpha", {"/cam": "NOT_OPERATIONAL", "/audio": "DEGRADED"})
    assert store.diagnosis("alpha").explanation.startswith("No failure diagnosed, but /audio")
    store.put_entity(rid, 3, cause="camera publishes too slowly", actions="check the cable")
    store.put_diagnosis(rid, ["/cam"], T0)
    store.flush()
    d = store.diagnosis("alpha")
    assert d.components == ("/cam",)
    assert d.explanation == ("The black box diagnoses /cam: /cam is not working. "
                             "/cam: camera publishes too slowly. "
                             "What to do for /cam: check the cable.")


def test_characteristics_carry_value_unit_thresholds_and_a_thinned_series(
        store: StationStore, clock: Clock) -> None:
    rid = robot(store, "alpha", {"/cam": "OPERATIONAL"})
    store.put_characteristic(rid, 50, entity=2, name="hz /cam period", observer="hz",
                             quantity="period", unit="s", expected_noise=float("nan"))
    store.put_threshold(rid, 60, 50, "max", "max", 0.1)
    store.put_threshold(rid, 61, 50, "min", "min", 0.01)
    for i in range(100):
        store.put_value(rid, 50, T0 - 99 + i, i / 100)
    store.put_value(rid, 50, T0 - 500, 7.0)  # late and old: a chart point, not the value
    store.put_value(rid, 50, T0, float("inf"))  # not finite: ignored
    store.flush()
    [c] = store.characteristics("alpha", entity=2)
    assert (c.value, c.time, c.unit, c.entity_name) == (0.99, T0, "s", "/cam")
    assert c.expected_noise is None
    assert [(t.type, t.value) for t in c.thresholds] == [("min", 0.01), ("max", 0.1)]
    series = store.series("alpha", 50, since=T0 - 1000)
    assert len(series) == 101 and series[0].value == 7.0 and series[-1].value == 0.99
    thin = store.series("alpha", 50, since=T0 - 99, max_points=10)
    assert len(thin) == 10 and thin[0].time == T0 - 99
    assert store.characteristics("alpha", entity=99) == []


def test_old_chart_points_are_pruned_after_the_retention(tmp_path: Path, clock: Clock) -> None:
    s = StationStore.open(tmp_path / "s.db", series_retention=60.0, clock=clock)
    try:
        rid = robot(s, "alpha", {})
        s.put_value(rid, 50, T0 - 120, 1.0)
        s.put_value(rid, 50, T0 - 20, 2.0)
        s.flush()
        clock.now += 31  # prunes at most every 30 s, when nothing waits
        s.flush()
        s.flush()
        assert [p.value for p in s.series(rid, 50, since=0)] == [2.0]
    finally:
        s.close()


def _events(store: StationStore, rid: int, n: int) -> None:
    for i in range(n):
        kind = ("failure", "exceedance", "rectification")[i % 3]
        store.add_event(rid, T0 + i, kind, dedup=f"{kind}|{i}", entity=f"/n{i % 2}",
                        text=f"event {i}")
    store.flush()


def test_events_filter_by_robot_entity_kind_and_time_and_page_without_gaps(
        store: StationStore) -> None:
    a = robot(store, "alpha", {})
    b = robot(store, "bravo", {})
    _events(store, a, 250)
    _events(store, b, 10)
    assert store.count_events() == 260
    page = store.events("alpha", kinds=["failure"], entity="/n0", since=T0 + 10,
                        until=T0 + 100)
    assert [e.time - T0 for e in page.events] == [96, 90, 84, 78, 72, 66, 60, 54, 48, 42,
                                                  36, 30, 24, 18, 12]
    seen: list[int] = []
    cursor = None
    while True:
        page = store.events("alpha", cursor=cursor, limit=40)
        seen.extend(e.id for e in page.events)
        if page.next_cursor is None:
            break
        cursor = page.next_cursor
    assert len(seen) == len(set(seen)) == 250
    assert len(store.events(limit=10**9).events) == 260  # capped at 1000
    with pytest.raises(ValueError, match="unknown event kind"):
        store.events(kinds=["exceedence"])
    with pytest.raises(ValueError, match="cursor"):
        store.events(cursor="yesterday")


def test_the_same_event_heard_live_and_fetched_from_the_log_is_stored_once(
        store: StationStore) -> None:
    rid = robot(store, "alpha", {})
    store.add_event(rid, T0, "failure", dedup="failure|1800000000.000|/cam", entity="/cam")
    store.add_event(rid, T0, "failure", dedup="failure|1800000000.000|/cam", entity="/cam",
                    origin="log")
    store.flush()
    assert [e.origin for e in store.events(rid).events] == ["live"]
    assert store.last_event_time(rid) == T0
    with pytest.raises(ValueError):
        store.add_event(rid, T0, "exceedence", dedup="x")


def test_acknowledging_marks_the_event_and_adds_one_to_the_timeline(
        store: StationStore, clock: Clock) -> None:
    rid = robot(store, "alpha", {})
    store.add_event(rid, T0, "failure", dedup="f", entity="/cam", text="cam down")
    store.flush()
    [event] = store.events(rid).events
    assert store.robot(rid).unacknowledged == 1
    clock.now += 5
    acked = store.acknowledge(event.id, "olivia", "on it")
    assert (acked.acknowledged_by, acked.acknowledged_at) == ("olivia", T0 + 5)
    assert store.acknowledge(event.id, "mallory").acknowledged_by == "olivia"
    ack = store.events(rid, kinds=["acknowledgement"]).events
    assert len(ack) == 1 and ack[0].refers_to == event.id and "on it" in ack[0].text
    assert store.robot(rid).unacknowledged == 0
    assert store.events(rid, unacknowledged=True).events == ()
    with pytest.raises(LookupError):
        store.acknowledge(10**6, "olivia")


def test_subscribers_hear_of_each_committed_change_and_learn_when_they_fell_behind(
        store: StationStore) -> None:
    heard: list[int] = []
    remove = store.add_listener(lambda c: heard.append(c.seq))
    with store.subscribe(maxsize=2) as sub:
        rid = robot(store, "alpha", {})
        change = sub.get(timeout=1)
        assert change is not None and rid in change.robots
        assert {"fleet", "entities"} <= change.topics and not change.overflow
        assert sub.get(timeout=0.01) is None
        for i in range(5):
            store.add_event(rid, T0 + i, "failure", dedup=str(i))
            store.flush()
        got = [sub.get(timeout=1), sub.get(timeout=1)]
        assert all(c is not None for c in got)
        assert got[0].overflow  # type: ignore[union-attr]
        assert got[-1].seq == store.sequence  # type: ignore[union-attr]
    remove()
    store.add_event(rid, T0 + 9, "failure", dedup="9")
    store.flush()
    assert heard == list(range(1, store.sequence))
    seq = store.sequence
    threading.Timer(0.05, lambda: (store.add_event(rid, T0, "ibit", dedup="i"),
                                   store.flush())).start()
    assert store.wait_for_change(seq, timeout=5) == seq + 1


def test_log_rows_download_as_jsonl_csv_and_mcap(store: StationStore) -> None:
    rid = robot(store, "alpha", {})
    request = store.create_log_request(rid, "alpha", entity=None, characteristic=None,
                                       since=T0, until=T0 + 10, kinds=[], requested_by="o")
    entries = [LogEntry(i, T0 + i, "failure", "/cam", None, None, {"n": i}) for i in range(1500)]
    store.add_log_rows(request, 0, entries[:1000])
    store.add_log_rows(request, 1000, entries[1000:])
    store.update_log_request(request, rid, status="done", rows=1500, pages=2, progress=1.0)
    store.flush()
    info = store.log_request(request)
    assert info is not None and (info.status, info.rows, info.requested_by) == ("done", 1500, "o")
    assert store.log_entries(request, 1490, 100) == entries[1490:]
    text = io.StringIO()
    assert store.export_log(request, "jsonl", text) == 1500
    assert read_jsonl(text.getvalue().splitlines()) == entries
    table = io.StringIO()
    store.export_log(request, "csv", table)
    assert table.getvalue().count("\n") == 1501
    from mcap.reader import make_reader

    binary = io.BytesIO()
    assert store.export_log(request, "mcap", binary) == 1500
    binary.seek(0)
    messages = list(make_reader(binary).iter_messages())
    assert [json.loads(m.data)["id"] for _, _, m in messages] == list(range(1500))
    with pytest.raises(ValueError):
        store.export_log(request, "xlsx", io.StringIO())
    assert [r.id for r in store.log_requests("alpha")] == [request]


@pytest.fixture(params=FULL_DISK_VARIANTS)
def full_disk(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[FullDisk]:
    with full_disk_in(request.param, tmp_path) as disk:
        yield disk


def test_a_full_disk_is_reported_keeps_what_was_stored_and_writing_resumes(
        full_disk: FullDisk, clock: Clock) -> None:
    store = StationStore.open(full_disk.directory / "station.db", clock=clock)
    try:
        rid = robot(store, "alpha", {"/cam": "OPERATIONAL"})
        store.add_event(rid, T0, "failure", dedup="before", text="stored before")
        assert store.flush()
        full_disk.fill(store)
        for i in range(3000):  # enough to need new pages
            store.add_event(rid, T0 + 1 + i, "exceedance", dedup=f"during {i}",
                            text="x" * 200)
        assert not store.flush(force=True)
        assert store.pending > 0
        problems = store.problems()
        assert problems and "full" in problems[0].message
        assert [e.text for e in store.events(rid).events] == ["stored before"]
        assert store.robot("alpha").status == "OPERATIONAL"  # reads keep working
        with pytest.raises(StationStoreError):
            store.acknowledge(store.events(rid).events[0].id, "olivia")
        full_disk.free(store)
        clock.now += 2
        assert store.flush()
        assert store.pending == 0
        assert store.count_events(rid) == 3000 + 1 + 1  # + the acknowledgement
        assert store.events(rid, kinds=["failure"]).events[0].acknowledged_by == "olivia"
        assert any(p.source == "store-recovered" for p in store.problems())
    finally:
        store.close()
    db = sqlite3.connect(full_disk.directory / "station.db")
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    db.close()


def test_while_the_disk_stays_full_chart_points_go_first_and_events_are_kept(
        tmp_path: Path, clock: Clock) -> None:
    store = StationStore.open(tmp_path / "s.db", clock=clock, max_pending=1000)
    try:
        rid = robot(store, "alpha", {})
        FullDisk("page_limit", tmp_path).fill(store)
        for i in range(600):  # one point each of 600 characteristics: nothing to coalesce
            store.put_value(rid, 1000 + i, T0 + i, float(i))
        for i in range(300):
            store.add_event(rid, T0 + i, "exceedance", dedup=str(i), text="y" * 500)
        assert not store.flush(force=True)
        assert store.pending <= 1000
        assert store.dropped_points > 0
        assert store.coalesced_points == 0
        assert any("dropped so far" in p.message for p in store.problems())
        FullDisk("page_limit", tmp_path).free(store)
        assert store.flush(force=True)
        assert store.count_events(rid) == 300
        assert len(store.characteristics(rid)) == 600  # every current value kept
    finally:
        store.close()


def test_a_full_write_queue_coalesces_a_characteristics_points_the_newest_wins(
        tmp_path: Path, clock: Clock) -> None:
    store = StationStore.open(tmp_path / "s.db", clock=clock, max_pending=1000)
    try:
        rid = robot(store, "alpha", {})
        FullDisk("page_limit", tmp_path).fill(store)
        for i in range(900):
            store.put_value(rid, 50, T0 + i, float(i))
        for i in range(300):
            store.add_event(rid, T0 + i, "exceedance", dedup=str(i), text="y" * 500)
        assert not store.flush(force=True)
        assert store.pending <= 1000
        assert store.coalesced_points > 0
        assert store.dropped_points == 0
        assert any("coalesced" in p.message for p in store.problems())
        FullDisk("page_limit", tmp_path).free(store)
        assert store.flush(force=True)
        assert store.count_events(rid) == 300
        points = store.series(rid, 50, since=T0 - 1)
        assert points[-1].value == 899.0  # the newest point of the characteristic
        assert len(points) + store.coalesced_points == 900  # each point stored or counted
    finally:
        store.close()
