"""Bad input from a fleet, with real processes over real Cyclone DDS on loopback: robots
are lightweight black boxes (``benchmarks/station_fleet.py --robots-child``, a real
``DdsHealthSink`` each) in their own processes, the station follower in this one.

* a robot whose clock is five minutes ahead (faked at the source: every time it stamps is
  its own wrong clock's): the station places its events at its own receive time, keeps the
  robot's time in the details, and shows the skew as a problem;
* two black boxes claiming one robot id at once: their boots interleave, a problem says
  so, and the events of both are stored, none lost.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.station.follow import StationFollower
from blackbox.station.store import StationStore, UnknownRobot
from blackbox.transport.participant import TransportSettings
from conftest import wait_until
from isolation import fresh_domain

pytestmark = pytest.mark.dds
ROBOTS = Path(__file__).resolve().parents[1] / "benchmarks" / "station_fleet.py"


def robots(domain: int, robot_id: str, index: int, *extra: str) -> subprocess.Popen[str]:
    env = dict(os.environ)
    env.pop("CYCLONEDDS_URI", None)  # the built-in loopback configuration applies
    proc = subprocess.Popen(
        [sys.executable, str(ROBOTS), "--robots-child", "--ids", robot_id, "--domain",
         str(domain), "--duration", "16", "--interval", "0.5", "--fault-every", "5",
         "--fault-length", "2", "--fault-start", "3", "--index", str(index), "--matched",
         *extra],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    # "ready" once the station's readers matched this robot (bounded by the robot: 600 s),
    # so that what the test counts is delivery, not a discovery still under way
    assert line == "ready", f"robot {robot_id} did not start: {line} {proc.stderr.read()}"
    return proc


def published(proc: subprocess.Popen[str]) -> dict[str, int]:
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    counts: dict[str, int] = next(iter(json.loads(out.strip().splitlines()[-1]).values()))
    return counts


@pytest.fixture
def station(tmp_path: Path) -> Iterator[tuple[StationStore, StationFollower, int]]:
    domain = fresh_domain()
    store = StationStore.open(tmp_path / "station.db", stale_after=30.0)
    follower = StationFollower(store, TransportSettings(domain), backfill=0)
    follower.start()
    try:
        yield store, follower, domain
    finally:
        follower.stop()
        store.close()


def events_of(store: StationStore, robot: str, kind: str) -> list[tuple[float, dict[str, object]]]:
    try:
        return [(e.time, e.details) for e in store.events(robot, kinds=[kind], limit=1000).events]
    except UnknownRobot:
        return []


@pytest.mark.xdist_group("fleet-bad-input")
def test_a_robot_clock_minutes_ahead_is_a_problem_and_its_events_go_at_the_station_time(
        station: tuple[StationStore, StationFollower, int]) -> None:
    store, _, domain = station
    started = time.time()
    robot = robots(domain, "skewed", 0, "--clock-offset", "300")
    try:
        wait_until(lambda: len(events_of(store, "skewed", "failure")) >= 2,
                   "two failures of the robot with the wrong clock", timeout=60)
        problems = {p.source: p.message for p in store.problems()}
        assert problems.get("clock skewed") == (
            "skewed: its clock is 5 min ahead of the station's; its events are placed at "
            "the time the station received them"), problems
        for at, details in events_of(store, "skewed", "failure"):
            assert started <= at <= time.time(), "placed at the station's receive time"
            assert isinstance(details["robot_time"], float)
            assert 295 < details["robot_time"] - at < 305, "the robot's own time is kept"
    finally:
        counts = published(robot)
    wait_until(lambda: len(events_of(store, "skewed", "failure")) == counts["failures"],
               f"all {counts['failures']} failures of the robot with the wrong clock")
    times = [at for at, _ in events_of(store, "skewed", "failure")]
    assert times == sorted(times, reverse=True), "newest first, by the station's clock"


@pytest.mark.xdist_group("fleet-bad-input")
def test_two_black_boxes_with_one_robot_id_are_a_problem_and_nothing_of_either_is_lost(
        station: tuple[StationStore, StationFollower, int]) -> None:
    store, _, domain = station
    first = robots(domain, "twin", 0)
    second = robots(domain, "twin", 1)
    wait_until(lambda: any(p.source == "robot id twin" for p in store.problems()),
               "the problem naming the robot id two black boxes share", timeout=60)
    message = next(p.message for p in store.problems() if p.source == "robot id twin")
    assert message.startswith("twin: two black boxes use this robot id at once (boots ")
    assert message.endswith("interleave); the events of both are kept; give one of them "
                            "its own robot id")
    counts = [published(first), published(second)]
    failures = sum(c["failures"] for c in counts)
    rectifications = sum(c["rectifications"] for c in counts)
    assert failures >= 4, counts
    wait_until(lambda: (len(events_of(store, "twin", "failure")),
                        len(events_of(store, "twin", "rectification")))
               == (failures, rectifications),
               f"{failures} failures and {rectifications} rectifications of both black boxes")
    boots = {str(d["event_id"]).split("-")[0] for _, d in events_of(store, "twin", "failure")}
    assert len(boots) == 2, f"the failures of both boots: {boots}"
