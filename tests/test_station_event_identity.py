"""Events have identities: a station stores each event a robot emitted exactly once, however
many share a millisecond, whether heard live over DDS or fetched from the robot's log, and
tells the operator when a robot's numbered events did not all arrive."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.identity import EventId, EventLedger
from blackbox.station.sequence import EventSequences
from blackbox.station.store import StationStore, UnknownRobot
from conftest import wait_until
from isolation import fresh_domain
from test_station_follow import NewBox, following, new_box  # noqa: F401

BURST = 500
"""Fault/recovery pairs in one burst: 1,000 failure and rectification events."""


def wait(condition: Callable[[], Any], what: str, timeout: float = 60.0) -> Any:
    return wait_until(condition, what, timeout)


def counts(store: StationStore, robot: str) -> dict[str, int]:
    try:
        return {k: store.count_events(robot, kinds=[k])
                for k in ("failure", "rectification", "exceedance")}
    except UnknownRobot:
        return {}


# ---- the identity itself (pure) ------------------------------------------------------------

def test_one_event_asked_for_twice_has_one_identity_and_numbers_have_no_holes() -> None:
    ledger = EventLedger()
    first = ledger.assign("failure", "/usb_cam", 100.0)
    assert ledger.assign("failure", "/usb_cam", 100.0) == first  # the recorder asks again
    assert ledger.lookup("failure", "/usb_cam", 100.0) == first
    assert ledger.lookup("failure", "/usb_cam", 100.000001) is None
    same_time = ledger.assign("rectification", "/usb_cam", 100.0)
    later = ledger.assign("failure", "/usb_cam", 100.0 + 1e-9)
    assert [first.sequence, same_time.sequence, later.sequence] == [1, 2, 3]
    assert ledger.at(100.0, ("failure", "rectification")) == [
        ("failure", "/usb_cam", first), ("rectification", "/usb_cam", same_time)]
    assert EventId.parse(str(later)) == later


def test_two_starts_of_a_black_box_never_share_identities() -> None:
    a, b = EventLedger(), EventLedger()
    assert a.boot != b.boot
    assert a.assign("failure", "x", 1.0) != b.assign("failure", "x", 1.0)


@pytest.mark.parametrize("text", ["", "1-1", "0123456789abcdef-0", "0123456789abcdef-01",
                                  "0123456789ABCDEF-1", "0123456789abcdef-1 ", "x" * 5000,
                                  "0123456789abcdef-99999999999999999999"])
def test_an_identity_from_the_network_is_parsed_strictly(text: str) -> None:
    assert EventId.parse(text) is None


def test_a_hole_in_the_numbers_counts_once_it_stays_open_and_closes_when_filled() -> None:
    seqs = EventSequences(grace=2.0)
    boot = "0123456789abcdef"
    for n, t in ((4, 10.0), (5, 11.0), (8, 14.0), (6, 12.0)):
        seqs.see(EventId(boot, n), t, now=20.0)
    assert seqs.gaps(21.0) == []  # 7 may still be on its way over another topic
    (gap,) = seqs.gaps(22.0)
    assert (gap.first, gap.last, gap.after) == (7, 7, 12.0)
    assert seqs.missing() == 1
    seqs.see(EventId(boot, 7), 13.0, now=23.0)
    assert seqs.gaps(100.0) == [] and seqs.missing() == 0


def test_a_hole_the_log_cannot_fill_is_given_up_and_counted() -> None:
    seqs = EventSequences(grace=0.0)
    boot = "0123456789abcdef"
    for n in (1, 4, 5, 9):
        seqs.see(EventId(boot, n), float(n), now=0.0)
    gaps = seqs.gaps(1.0)
    assert [(g.first, g.last) for g in gaps] == [(2, 3), (6, 8)]
    seqs.give_up(gaps[0])
    assert [(g.first, g.last) for g in seqs.gaps(1.0)] == [(6, 8)]
    seqs.give_up(seqs.gaps(1.0)[0])
    assert seqs.gaps(1.0) == [] and seqs.given_up == 5
    seqs.see(EventId(boot, 10), 10.0, now=2.0)  # numbering goes on after the loss
    assert seqs.gaps(100.0) == []


# ---- through real DDS and a real log ---------------------------------------------------------

@pytest.mark.dds
def test_a_burst_of_a_thousand_events_heard_live_is_stored_exactly_once_each(
        tmp_path: Path, new_box: NewBox) -> None:  # noqa: F811
    domain = fresh_domain()
    box = new_box("burst", domain, "ok")
    with following(tmp_path / "station.db", domain, backfill=0) as (store, _follower):
        wait(lambda: "/usb_cam" in {e.name for e in _entities(store, "burst")},
             "the robot's entities")
        box.send(f"burst {BURST}")
        # each kind is a topic of its own: the exceedances may come after the rest
        wait(lambda: all(counts(store, "burst").get(kind, 0) >= BURST
                         for kind in ("failure", "rectification", "exceedance")),
             f"{BURST} failures, rectifications and exceedances")
        assert counts(store, "burst") == {"failure": BURST, "rectification": BURST,
                                          "exceedance": BURST}
        events = store.events("burst", kinds=["failure", "rectification"], limit=2 * BURST).events
        ids = {e.details.get("event_id") for e in events}
        assert len(ids) == 2 * BURST and all(EventId.parse(str(i)) for i in ids)
        stamps = [round(e.time, 3) for e in events]
        assert len(set(stamps)) < len(stamps)  # many shared a millisecond, none was lost
        assert not [p for p in store.problems() if "events" in p.source]


@pytest.mark.dds
def test_a_burst_fetched_from_the_robots_log_is_stored_exactly_once_each(
        tmp_path: Path, new_box: NewBox) -> None:  # noqa: F811
    domain = fresh_domain()
    new_box("burst", domain, "ok", f"burst {BURST}", store=tmp_path / "robot.db")
    with following(tmp_path / "station.db", domain, backfill=600) as (store, _follower):
        wait(lambda: counts(store, "burst").get("rectification") == BURST
             and counts(store, "burst").get("failure") == BURST,
             f"{BURST} failures and {BURST} rectifications from the robot's log")
        # The second backfill round finds the same rows again: nothing is added twice. A
        # round offers 5 events per pair: failure, rectification, the diagnosis each
        # changes, and the exceedance that started the fault.
        wait(lambda: _follower.stats.backfilled >= 2 * 5 * BURST, "both backfill rounds")
        assert counts(store, "burst") == {"failure": BURST, "rectification": BURST,
                                          "exceedance": BURST}


@pytest.mark.dds
def test_events_lost_on_the_network_are_noticed_by_number_and_fetched_from_the_log(
        tmp_path: Path, new_box: NewBox) -> None:  # noqa: F811
    domain = fresh_domain()
    box = new_box("lossy", domain, "ok", "fault", "ok", store=tmp_path / "robot.db")
    with following(tmp_path / "station.db", domain, backfill=600) as (store, follower):
        wait(lambda: counts(store, "lossy").get("rectification") == 1, "the live recovery")
        robot = next(r for r in follower._robots.values() if r.robot_id == "lossy")
        # The backfills on first sight are over: from now on only a hole brings the log.
        wait(lambda: not robot.backfill_due and follower._backfills.jobs.empty()
             and not follower._backfills.lock.locked(), "the first backfills to end")
        fetched_before = follower.stats.backfilled
        box.send("unpublished 3")
        box.send("fault")
        box.send("ok")
        wait(lambda: counts(store, "lossy").get("failure") == 5
             and counts(store, "lossy").get("rectification") == 5,
             "the 3 lost failures and recoveries, and the 2 heard after them")
        assert follower.stats.backfilled > fetched_before
        assert follower.stats.events_lost == 0
        assert not [p for p in store.problems() if p.source.startswith("lost events")]


@pytest.mark.dds
def test_a_change_of_state_lost_on_the_network_is_fetched_from_the_log_not_reported_lost(
        tmp_path: Path, new_box: NewBox) -> None:  # noqa: F811
    domain = fresh_domain()
    box = new_box("lossy", domain, "ok", "fault", "ok", store=tmp_path / "robot.db")
    with following(tmp_path / "station.db", domain, backfill=600) as (store, follower):
        wait(lambda: counts(store, "lossy").get("rectification") == 1, "the live recovery")
        robot = next(r for r in follower._robots.values() if r.robot_id == "lossy")
        wait(lambda: not robot.backfill_due and follower._backfills.jobs.empty()
             and not follower._backfills.lock.locked(), "the first backfills to end")
        box.send("unpublished-state")  # numbered and logged (an observation row), not sent
        box.send("ok")  # back to "ok": a change of state heard live, after the hole

        def state_changes() -> list[str]:
            return sorted(e.origin for e in store.events("lossy", kinds=["state_change"]).events)

        wait(lambda: state_changes() == ["live", "log"]
             and not [p for p in store.problems() if p.source.startswith("missing events")]
             and not robot.gap_fetch,
             "the lost change of state fetched from the log and the hole closed")
        assert follower.stats.events_lost == 0
        assert not [p for p in store.problems() if p.source.startswith("lost events")]


def _entities(store: StationStore, robot: str) -> Iterator[Any]:
    try:
        yield from store.entities(robot)
    except UnknownRobot:
        return
