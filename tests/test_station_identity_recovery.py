"""Events have identities, and a station stores each event a robot numbered exactly once,
whatever arrived late or not at all:

* a numbered change of state missed live is in the robot's log as an ``observation`` row:
  the backfill fetches it, the hole in the numbers closes, and only numbers the log lacks
  too are reported missing;
* an identity (extension sample) that arrives after its event was stored under its time
  key is matched back to that row, so the copy the robot's log supplies meets it.

Everything but DDS is real: the robot's health mapper and recorder share one event ledger
and write a real log file; the station follower writes a real SQLite station database and
is handed the samples batch by batch (``ingest``) and the robot's log as a backfill fetches
it (``take_logged``: the rows of ``BACKFILL_KINDS``).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.extension import C_Event_Extension, T_EventKind
from blackbox.health.identity import EventId, EventLedger
from blackbox.health.mapping import HealthMapper
from blackbox.model import Diagnosis, Observation
from blackbox.record import Recorder, Store
from blackbox.record.settings import RecorderSettings
from blackbox.record.store import LogEntry
from blackbox.station.follow import BACKFILL_KINDS, EXT_WAIT_MAX, FOLLOWED, StationFollower
from blackbox.station.store import StationStore
from blackbox.transport.topics import TOPIC_OF_TYPE
from dds_blackbox_driver import fast, faulty, healthy

EXTENSION = "BlackBox_Event_Extension"
KINDS = ("failure", "rectification", "exceedance", "state_change")


STEP = 0.0001
"""Seconds between two cycles of the robot: ten in one millisecond, as in a burst, however
busy the machine running the test is."""


class Robot:
    """A black box's health mapper (publishes, assigns the numbers) and recorder (logs),
    sharing one event ledger, as ``blackbox.app`` composes them. Its clock starts now and
    advances ``STEP`` per cycle."""

    def __init__(self, directory: Path) -> None:
        self.ledger = EventLedger()
        self.mapper = HealthMapper("burst", ledger=self.ledger)
        self.path = directory / "robot.db"
        self.recorder = Recorder(RecorderSettings(str(self.path), commit_interval=0.1),
                                 robot_id="burst", ledger=self.ledger)
        self.published: list[tuple[str, Any]] = []
        self.time = time.time()
        self._publish(self.mapper.start(self.time))

    def _publish(self, samples: list[Any]) -> list[tuple[str, Any]]:
        out = [(TOPIC_OF_TYPE[type(s)], s) for s in samples]
        out = [item for item in out if item[0] in FOLLOWED]
        self.published += out
        return out

    def step(self, observe: Callable[[float], list[Observation]],
             diagnosed: bool = False) -> list[tuple[str, Any]]:
        """One cycle: observations, then the diagnosis; returns what was published."""
        self.time += STEP
        t = self.time
        obs = observe(t)
        diagnosis = Diagnosis(t, (frozenset({"/usb_cam"}),), (obs[0],), "too slow") \
            if diagnosed else Diagnosis(t, ())
        out = self._publish(self.mapper.observations(t, obs) + self.mapper.diagnosis(diagnosis))
        self.recorder.on_observations(t, obs)
        self.recorder.on_diagnosis(diagnosis)
        return out

    def log(self) -> list[LogEntry]:
        """The robot's log as the station's backfill asks for it."""
        self.recorder.close()
        with Store.open(self.path, readonly=True) as log:
            return list(log.query(kinds=list(BACKFILL_KINDS)))


def without(samples: list[tuple[str, Any]],
            lost: list[tuple[str, Any]]) -> list[tuple[str, Any]]:
    gone = {id(s) for _, s in lost}
    return [item for item in samples if id(item[1]) not in gone]


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


def missing_numbers(store: StationStore) -> list[str]:
    """The numbers the station tells the operator it misses ("numbers 4, 7-9")."""
    for p in store.problems():
        if p.source == "missing events burst":
            found = re.search(r"\(numbers ([^;)]*)", p.message)
            assert found, p.message
            return found.group(1).split(", ")
    return []


def heard_first(robot: Robot) -> None:
    """A fault and its recovery heard live: the station knows where the robot's numbers
    stand (what came before the first number it heard is the first backfill's job)."""
    robot.step(healthy)
    robot.step(faulty, diagnosed=True)
    robot.step(healthy)


# ---- a numbered change of state missed live -------------------------------------------------

def test_a_change_of_state_missed_live_is_fetched_from_the_log_and_closes_its_hole(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    lost = robot.step(fast)  # the change of state is numbered, logged, and lost on the way
    assert any(isinstance(s, C_Event_Extension) and s.A_eventId for _, s in lost)
    robot.step(healthy)  # back to "ok": another change of state, heard
    robot.step(faulty, diagnosed=True)
    robot.step(healthy)
    now = time.time()
    follower.ingest(without(robot.published, lost), now)
    store.flush(force=True)
    assert counts(store) == {"failure": 2, "rectification": 2, "exceedance": 2,
                             "state_change": 1}
    rid = store.resource_of("burst")
    follower.take_logged(rid, robot.log())
    follower.ingest([], now + 10.0)  # long after a hole would have been reported
    store.flush(force=True)
    assert missing_numbers(store) == []
    assert follower.stats.events_lost == 0
    assert counts(store) == {"failure": 2, "rectification": 2, "exceedance": 2,
                             "state_change": 2}
    logged = [e for e in store.events("burst", kinds=["state_change"]).events
              if e.origin == "log"]
    assert len(logged) == 1 and "fast" in logged[0].text
    assert EventId.parse(str(logged[0].details["event_id"]))


def test_only_numbers_the_log_lacks_too_are_reported_missing(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    lost = robot.step(fast)
    # A number used and then neither published nor logged (a log that lost its rows).
    absent = robot.ledger.assign("failure", "/ghost", robot.time)
    robot.step(healthy)
    robot.step(faulty, diagnosed=True)
    now = time.time()
    follower.ingest(without(robot.published, lost), now)
    store.flush(force=True)
    follower.take_logged(store.resource_of("burst"), robot.log())
    follower.ingest([], now + 10.0)
    store.flush(force=True)
    assert missing_numbers(store) == [str(absent.sequence)]


# ---- an identity that comes after its event was stored under its time key ----------------------

def split(samples: list[tuple[str, Any]]) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    """The event and state samples, and the extensions (identities) that may lag behind."""
    return ([item for item in samples if item[0] != EXTENSION],
            [item for item in samples if item[0] == EXTENSION])


def stored_under_time_keys(follower: StationFollower, samples: list[tuple[str, Any]],
                           start: float) -> list[tuple[str, Any]]:
    """Deliver the events while the extension reader stays behind until ``EXT_WAIT_MAX``
    passed: they are stored under their time keys. Returns the held-back extensions."""
    others, extensions = split(samples)
    follower.ingest(others, start, behind={EXTENSION})
    follower.ingest([], start + EXT_WAIT_MAX, behind={EXTENSION})
    follower.store.flush(force=True)
    return extensions


def test_an_identity_that_comes_late_renames_the_row_and_the_logged_copy_meets_it(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    start = time.time()
    follower.ingest(robot.published, start)
    late = robot.step(faulty, diagnosed=True) + robot.step(healthy)
    extensions = stored_under_time_keys(follower, late, start + 1.0)
    unnamed = [e for e in store.events("burst", kinds=["failure"]).events
               if not e.details.get("event_id")]
    assert len(unnamed) == 1  # stored without its identity
    follower.ingest(extensions, start + EXT_WAIT_MAX + 2.0)
    store.flush(force=True)
    failures = store.events("burst", kinds=["failure"]).events
    assert all(EventId.parse(str(e.details.get("event_id"))) for e in failures)
    assert [e.id for e in failures if e.id == unnamed[0].id]  # the same row, renamed
    follower.take_logged(store.resource_of("burst"), robot.log())
    follower.ingest([], start + EXT_WAIT_MAX + 20.0)
    store.flush(force=True)
    assert counts(store) == {"failure": 2, "rectification": 2, "exceedance": 2,
                             "state_change": 0}
    assert missing_numbers(store) == []


def rectifications(extensions: list[tuple[str, Any]]) -> list[tuple[str, Any]]:
    """The extensions that are events themselves (rectifications): the others name the
    failures and exceedances."""
    return [item for item in extensions if item[1].A_kind == T_EventKind.L_EventKind_RECTIFICATION]


def test_an_identity_lost_on_the_way_is_taken_from_the_logged_copy(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    start = time.time()
    follower.ingest(robot.published, start)
    late = robot.step(faulty, diagnosed=True) + robot.step(healthy)
    extensions = stored_under_time_keys(follower, late, start + 1.0)
    follower.ingest(rectifications(extensions), start + EXT_WAIT_MAX + 1.0)  # the rest lost
    store.flush(force=True)
    (unnamed,) = [e for e in store.events("burst", kinds=["failure"]).events
                  if not e.details.get("event_id")]
    store.acknowledge(unnamed.id, "ada", "seen on the robot page")
    # The numbers look missing: the backfill brings the logged copies, with identities.
    follower.take_logged(store.resource_of("burst"), robot.log())
    follower.ingest([], start + EXT_WAIT_MAX + 20.0)
    store.flush(force=True)
    assert counts(store) == {"failure": 2, "rectification": 2, "exceedance": 2,
                             "state_change": 0}
    assert missing_numbers(store) == []
    named = store.event(unnamed.id)
    assert named is not None and named.acknowledged_by == "ada" and named.origin == "live"
    assert EventId.parse(str(named.details.get("event_id")))
    assert named.text == unnamed.text  # what was heard live is kept


def test_a_live_event_stored_after_its_logged_copy_becomes_one_when_its_identity_comes(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    start = time.time()
    follower.ingest(robot.published, start)
    late = robot.step(faulty, diagnosed=True) + robot.step(healthy)
    store.flush(force=True)
    # The backfill was quicker than the live samples: the logged copies are stored first.
    follower.take_logged(store.resource_of("burst"), robot.log())
    extensions = stored_under_time_keys(follower, late, start + 1.0)
    assert counts(store)["failure"] == 3
    (unnamed,) = [e for e in store.events("burst", kinds=["failure"]).events
                  if not e.details.get("event_id")]
    store.acknowledge(unnamed.id, "ada", "seen on the robot page")
    follower.ingest(extensions, start + EXT_WAIT_MAX + 2.0)
    store.flush(force=True)
    assert counts(store) == {"failure": 2, "rectification": 2, "exceedance": 2,
                             "state_change": 0}
    failures = store.events("burst", kinds=["failure"]).events
    assert len({e.details.get("event_id") for e in failures}) == 2
    (acked,) = [e for e in failures if e.acknowledged_by]
    assert acked.acknowledged_by == "ada" and acked.origin == "log"
    (ack,) = store.events("burst", kinds=["acknowledgement"]).events
    assert ack.refers_to == acked.id


def test_events_of_one_millisecond_named_late_are_each_stored_once(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    start = time.time()
    follower.ingest(robot.published, start)
    pairs = 100
    late: list[tuple[str, Any]] = []
    for _ in range(pairs):
        late += robot.step(faulty, diagnosed=True) + robot.step(healthy)
    extensions = stored_under_time_keys(follower, late, start + 1.0)
    merged = counts(store)["failure"]
    assert merged < pairs  # events of one millisecond shared a time key
    follower.ingest(extensions, start + EXT_WAIT_MAX + 2.0)
    store.flush(force=True)
    expected = {"failure": pairs + 1, "rectification": pairs + 1, "exceedance": pairs + 1,
                "state_change": 0}
    assert counts(store) == expected
    follower.take_logged(store.resource_of("burst"), robot.log())
    follower.ingest([], start + EXT_WAIT_MAX + 20.0)
    store.flush(force=True)
    assert counts(store) == expected
    assert missing_numbers(store) == []


def test_events_of_one_millisecond_whose_identities_were_lost_are_each_stored_once(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    start = time.time()
    follower.ingest(robot.published, start)
    pairs = 100
    late: list[tuple[str, Any]] = []
    for _ in range(pairs):
        late += robot.step(faulty, diagnosed=True) + robot.step(healthy)
    extensions = stored_under_time_keys(follower, late, start + 1.0)
    follower.ingest(rectifications(extensions), start + EXT_WAIT_MAX + 1.0)  # the rest lost
    store.flush(force=True)
    assert counts(store)["failure"] < pairs  # events of one millisecond shared a time key
    follower.take_logged(store.resource_of("burst"), robot.log())
    follower.ingest([], start + EXT_WAIT_MAX + 20.0)
    store.flush(force=True)
    assert counts(store) == {"failure": pairs + 1, "rectification": pairs + 1,
                             "exceedance": pairs + 1, "state_change": 0}
    assert missing_numbers(store) == []


# ---- diagnoses: the robot's conclusion, each change kept -----------------------------------

def test_every_change_of_diagnosis_is_kept_and_the_newest_is_the_robots_current_one(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)
    pairs = 100
    for _ in range(pairs):
        robot.step(faulty, diagnosed=True)
        robot.step(healthy)
    robot.step(faulty, diagnosed=True)  # the robot ends faulty
    follower.ingest(robot.published, time.time())
    store.flush(force=True)
    log = robot.log()
    changes = [e for e in log if e.kind == "failure"]  # one row per change of diagnosis
    assert len({round(e.time, 3) for e in changes}) < len(changes)  # many in one ms
    diagnoses = store.count_events("burst", kinds=["diagnosis"])
    assert diagnoses == len(changes) == 2 * pairs + 3
    follower.take_logged(store.resource_of("burst"), log)
    store.flush(force=True)
    assert store.count_events("burst", kinds=["diagnosis"]) == diagnoses  # copies met
    (newest,) = store.events("burst", kinds=["diagnosis"], limit=1).events
    assert newest.details["components"] == ["/usb_cam"]
    assert next(s for s in store.fleet() if s.robot_id == "burst").diagnosis == ("/usb_cam",)


def test_an_event_stored_before_its_entity_was_described_meets_its_logged_copy(
        tmp_path: Path, station: tuple[StationStore, StationFollower]) -> None:
    """Stored under its time key and the entity's id (``#<id>``: the description had not
    come), renamed when the description came, the event is still the one its logged copy
    (which names the entity) finds: one row, not two."""
    store, follower = station
    robot = Robot(tmp_path)
    heard_first(robot)

    def camera_description(item: tuple[str, Any]) -> bool:
        return item[0] == "BlackBox_Entity_Description" and item[1].A_name == "/usb_cam"

    (description,) = [item for item in robot.published if camera_description(item)]
    start = time.time()
    follower.ingest([item for item in robot.published if not camera_description(item)], start)
    late = robot.step(faulty, diagnosed=True) + robot.step(healthy)
    extensions = stored_under_time_keys(follower, late, start + 1.0)
    follower.ingest(rectifications(extensions), start + EXT_WAIT_MAX + 1.0)  # the rest lost
    store.flush(force=True)
    iid = int(description[1].A_sourceID.A_instanceId)
    (unnamed,) = [e for e in store.events("burst", kinds=["failure"]).events
                  if not e.details.get("event_id")]
    assert unnamed.entity == f"#{iid}"
    follower.ingest([description], start + EXT_WAIT_MAX + 2.0)
    store.flush(force=True)
    assert store.event(unnamed.id).entity == "/usb_cam"  # type: ignore[union-attr]
    follower.take_logged(store.resource_of("burst"), robot.log())
    follower.ingest([], start + EXT_WAIT_MAX + 20.0)
    store.flush(force=True)
    assert counts(store) == {"failure": 2, "rectification": 2, "exceedance": 2,
                             "state_change": 0}
    named = store.event(unnamed.id)
    assert named is not None and EventId.parse(str(named.details.get("event_id")))
