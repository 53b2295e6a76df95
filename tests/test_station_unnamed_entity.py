"""A rectification the station hears before the description of its entity is stored under
the entity's id (``#<id>``) and reads "#<id> is no longer diagnosed faulty"; when the
description comes, the stored event takes the entity's name and its words name it
(review item 4), also when the station restarted in between.

Everything but DDS is real: the robot's health mapper makes the samples, the station
follower writes a real SQLite station database; the follower is handed the samples as
its readers would deliver them, the entity's description held back."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.identity import EventLedger
from blackbox.health.mapping import HealthMapper
from blackbox.model import Diagnosis
from blackbox.station.follow import EXT_WAIT_MAX, FOLLOWED, StationFollower
from blackbox.station.store import Event, StationStore
from blackbox.transport.participant import TransportSettings
from blackbox.transport.topics import TOPIC_OF_TYPE
from dds_blackbox_driver import faulty, healthy
from isolation import fresh_domain

ROBOT = "late-names"
CAMERA = "/usb_cam"
DESCRIPTION = "BlackBox_Entity_Description"


def published(start: float) -> list[tuple[str, Any]]:
    """What the robot publishes: its start, the camera diagnosed faulty, then healthy (a
    rectification)."""
    mapper = HealthMapper(ROBOT, ledger=EventLedger())
    out: list[Any] = list(mapper.start(start))
    for i, (observe, diagnosed) in enumerate(((healthy, False), (faulty, True),
                                              (healthy, False))):
        t = start + i
        obs = observe(t)
        out += mapper.observations(t, obs)
        out += mapper.diagnosis(Diagnosis(t, (frozenset({CAMERA}),), (obs[0],), "too slow")
                                if diagnosed else Diagnosis(t, ()))
    return [(TOPIC_OF_TYPE[type(s)], s) for s in out if TOPIC_OF_TYPE[type(s)] in FOLLOWED]


def is_camera_description(item: tuple[str, Any]) -> bool:
    return item[0] == DESCRIPTION and item[1].A_name == CAMERA


@pytest.fixture
def samples() -> tuple[list[tuple[str, Any]], tuple[str, Any], int]:
    """The robot's samples without the camera's description, that description, and the
    camera's instance id."""
    made = published(time.time())
    (camera,) = [item for item in made if is_camera_description(item)]
    return ([item for item in made if not is_camera_description(item)], camera,
            int(camera[1].A_sourceID.A_instanceId))


@pytest.fixture
def station(tmp_path: Path) -> Iterator[tuple[StationStore, StationFollower]]:
    store = StationStore.open(tmp_path / "station.db")
    try:
        yield store, StationFollower(store, backfill=0)
    finally:
        store.close()


def deliver(follower: StationFollower, taken: list[tuple[str, Any]], now: float) -> None:
    """One poll's samples, then a later empty poll: events no longer wait for extensions."""
    follower.ingest(taken, now)
    follower.ingest([], now + EXT_WAIT_MAX)
    follower.store.flush(force=True)


def rectification(store: StationStore) -> Event:
    (event,) = store.events(ROBOT, kinds=["rectification"]).events
    return event


def test_a_rectification_heard_before_its_entitys_description_names_it_once_described(
        station: tuple[StationStore, StationFollower],
        samples: tuple[list[tuple[str, Any]], tuple[str, Any], int]) -> None:
    store, follower = station
    without_camera, camera, iid = samples
    now = time.time()
    deliver(follower, without_camera, now)
    before = rectification(store)
    assert (before.entity, before.text) == (f"#{iid}", f"#{iid} is no longer diagnosed faulty")
    deliver(follower, [camera], now + 2 * EXT_WAIT_MAX)
    after = rectification(store)
    assert (after.id, after.entity, after.text) == (
        before.id, CAMERA, f"{CAMERA} is no longer diagnosed faulty")
    (failure,) = store.events(ROBOT, kinds=["failure"]).events
    assert failure.entity == CAMERA
    assert store.events(ROBOT, entity=CAMERA).events, "the camera's events are found by name"


@pytest.mark.dds
def test_a_description_that_comes_after_a_station_restart_still_names_the_rectification(
        tmp_path: Path, samples: tuple[list[tuple[str, Any]], tuple[str, Any], int],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The restarted station reads the unnamed entity back from its database (as
    ``#<id>``) when it opens; it joins a DDS domain of its own on loopback, where no robot
    publishes, and is handed the description as before."""
    monkeypatch.delenv("CYCLONEDDS_URI", raising=False)  # the station's own: loopback
    without_camera, camera, iid = samples
    now = time.time()
    store = StationStore.open(tmp_path / "station.db")
    try:
        deliver(StationFollower(store, backfill=0), without_camera, now)
        assert rectification(store).entity == f"#{iid}"
    finally:
        store.close()
    store = StationStore.open(tmp_path / "station.db")
    follower = StationFollower(store, TransportSettings(fresh_domain()), backfill=0)
    try:
        follower.open()  # reads what the database knows; no thread takes samples
        deliver(follower, [camera], now + 2 * EXT_WAIT_MAX)
        after = rectification(store)
        assert (after.entity, after.text) == (CAMERA, f"{CAMERA} is no longer diagnosed faulty")
    finally:
        follower.stop()
        store.close()


def test_a_description_heard_first_names_the_rectification_from_the_start(
        station: tuple[StationStore, StationFollower],
        samples: tuple[list[tuple[str, Any]], tuple[str, Any], int]) -> None:
    store, follower = station
    without_camera, camera, _ = samples
    deliver(follower, [camera, *without_camera], time.time())
    event = rectification(store)
    assert (event.entity, event.text) == (CAMERA, f"{CAMERA} is no longer diagnosed faulty")
