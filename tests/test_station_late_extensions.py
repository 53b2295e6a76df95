"""An event's identity travels on its own topic (``BlackBox_Event_Extension``), which carries
about three samples for each failure or exceedance sample. In a burst the station takes a
bounded number of samples per reader and poll, so the extension reader falls behind the
event readers by several polls. An event must keep waiting for its identity while its
extension is still queued: stored under a time key instead, its number looks missing, the
robot's log is fetched to fill the hole and the logged copy, keyed by its identity, is
stored a second time (a 4,000-event burst on PostgreSQL stored 3,021 failures for 2,000).

Everything but DDS is real: the robot's health mapper and recorder share one event ledger
and write a real log file; the station follower writes a real SQLite station database.
The follower is handed the samples poll by poll the way a lagging extension reader
delivers them, and then the robot's whole log, as a backfill after a hole would fetch it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.identity import EventId, EventLedger
from blackbox.health.mapping import HealthMapper
from blackbox.model import Diagnosis
from blackbox.record import Recorder, Store
from blackbox.record.settings import RecorderSettings
from blackbox.record.store import LogEntry
from blackbox.station.follow import (
    BACKFILL_KINDS,
    EXT_WAIT,
    EXT_WAIT_MAX,
    FOLLOWED,
    StationFollower,
)
from blackbox.station.store import StationStore
from blackbox.transport.topics import TOPIC_OF_TYPE
from dds_blackbox_driver import faulty, healthy

PAIRS = 200
"""Fault/recovery pairs in the burst: 200 failures, 200 rectifications, 200 exceedances."""
EXTENSION = "BlackBox_Event_Extension"
KINDS = ("failure", "rectification", "exceedance", "diagnosis")


@dataclass(frozen=True, slots=True)
class Burst:
    """What one robot published in a burst (``(topic, sample)`` in order) and its log."""

    samples: list[tuple[str, Any]]
    log: list[LogEntry]

    @property
    def extensions(self) -> list[tuple[str, Any]]:
        return [item for item in self.samples if item[0] == EXTENSION]

    @property
    def others(self) -> list[tuple[str, Any]]:
        return [item for item in self.samples if item[0] != EXTENSION]


def burst(directory: Path, pairs: int) -> Burst:
    """``pairs`` faults and recoveries of /usb_cam ten to a millisecond, published by the
    health mapper and logged by the recorder, as ``tests/dds_blackbox_driver.py`` does on
    ``burst N``."""
    ledger = EventLedger()
    mapper = HealthMapper("burst", ledger=ledger)
    recorder = Recorder(RecorderSettings(str(directory / "robot.db"), commit_interval=0.1),
                        robot_id="burst", ledger=ledger)
    published: list[Any] = []
    start = time.time()
    published += mapper.start(start)
    rounds = [(healthy, False)] + [(f, d) for _ in range(pairs)
                                   for f, d in ((faulty, True), (healthy, False))]
    for i, (observe, diagnosed) in enumerate(rounds):
        t = start + i * 1e-4  # a robot's clock in a burst: ten rounds a millisecond
        obs = observe(t)
        diagnosis = Diagnosis(t, (frozenset({"/usb_cam"}),), (obs[0],), "too slow") \
            if diagnosed else Diagnosis(t, ())
        published += mapper.observations(t, obs)  # the publisher first: it assigns the ids
        published += mapper.diagnosis(diagnosis)
        recorder.on_observations(t, obs)
        recorder.on_diagnosis(diagnosis)
    recorder.close()
    with Store.open(directory / "robot.db", readonly=True) as log:
        entries = list(log.query(kinds=list(BACKFILL_KINDS)))
    samples = [(TOPIC_OF_TYPE[type(s)], s) for s in published]
    return Burst([item for item in samples if item[0] in FOLLOWED], entries)


@pytest.fixture
def station(tmp_path: Path) -> Iterator[tuple[StationStore, StationFollower]]:
    """A station database file and a follower writing into it (fed by hand: no DDS)."""
    store = StationStore.open(tmp_path / "station.db")
    follower = StationFollower(store, backfill=600)
    try:
        yield store, follower
    finally:
        store.close()


def counts(store: StationStore) -> dict[str, int]:
    return {k: store.count_events("burst", kinds=[k]) for k in KINDS}


def deliver_with_lagging_extensions(follower: StationFollower, made: Burst, start: float,
                                    first: int = 1) -> float:
    """The event and state readers are drained in the first poll, which takes ``first``
    extensions; the extension reader then hands over a third of its samples per poll, a
    poll every ``EXT_WAIT`` + 0.5 s, and is behind until its last take. Returns the time
    of the last poll."""
    extensions = made.extensions
    third = len(extensions) // 3 + 1
    now = start
    follower.ingest(made.others + extensions[:first], now, behind={EXTENSION})
    rest = extensions[first:]
    while rest:
        now += EXT_WAIT + 0.5
        take, rest = rest[:third], rest[third:]
        follower.ingest(take, now, behind={EXTENSION} if rest else set())
    now += EXT_WAIT + 0.5
    follower.ingest([], now)
    follower.store.flush(force=True)
    return now


def test_events_whose_identities_lag_behind_are_stored_once_live_and_once_in_all(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    made = burst(tmp_path, PAIRS)
    stamps = [e.time for e in made.log if e.kind == "failure"]
    assert len({round(t, 3) for t in stamps}) < len(stamps)  # many shared a millisecond
    deliver_with_lagging_extensions(follower, made, time.time())
    live = counts(store)
    assert (live["failure"], live["rectification"], live["exceedance"]) == (PAIRS,) * 3
    failures = store.events("burst", kinds=["failure"], limit=PAIRS).events
    assert all(EventId.parse(str(e.details.get("event_id"))) for e in failures)
    assert not [p for p in store.problems() if "events" in p.source]  # no hole was seen
    # The robot's log, as the backfill fetches it: every row meets its live copy.
    rid = store.resource_of("burst")
    assert follower.take_logged(rid, made.log) > 0
    store.flush(force=True)
    assert counts(store) == live


def test_a_rectification_announced_late_is_not_also_inferred_from_the_entity_state(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    made = burst(tmp_path, 20)
    # The entity's failure count drops to 0 twenty times before any extension arrives:
    # the robot names its rectifications itself, the station must not add its own.
    deliver_with_lagging_extensions(follower, made, time.time(), first=0)
    assert counts(store)["rectification"] == 20


def test_an_event_whose_identity_never_comes_is_kept_under_its_time(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    made = burst(tmp_path, 1)
    start = time.time()
    # The extension reader stays behind and never hands over the failure's identity.
    follower.ingest(made.others, start, behind={EXTENSION})
    follower.ingest([], start + EXT_WAIT_MAX - 0.5, behind={EXTENSION})
    store.flush(force=True)
    assert counts(store)["failure"] == 0  # still waiting: the extension may be queued
    follower.ingest([], start + EXT_WAIT_MAX, behind={EXTENSION})
    store.flush(force=True)
    (failure,) = store.events("burst", kinds=["failure"]).events
    assert failure.entity == "/usb_cam" and not failure.details.get("event_id")
