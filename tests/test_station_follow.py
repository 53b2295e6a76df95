"""The station follower against black boxes in other processes, over Cyclone DDS on
loopback, into a real station database file: live state and events, restarts without
loss or duplicates, log requests, built-in tests, bad input and a full disk."""

from __future__ import annotations

import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Protocol

import psutil
import pytest

from blackbox.record import Store
from blackbox.station.follow import StationFollower
from blackbox.station.store import StationStore, UnknownRobot
from blackbox.transport.participant import TransportSettings
from conftest import wait_until
from isolation import fresh_domain
from station_support import (
    FULL_DISK_VARIANTS,
    ScriptedBlackBox,
    dds_env,
    full_disk_in,
    station_signer_for_tests,
    trusting_thesis_config,
)

pytestmark = pytest.mark.dds

HERE = Path(__file__).parent



def wait(condition: Callable[[], Any], timeout: float = 15.0) -> Any:
    return wait_until(condition, timeout=timeout)


def health(store: StationStore, robot: str) -> dict[str, str]:
    try:
        return {e.name: e.reported_status for e in store.entities(robot)}
    except UnknownRobot:
        return {}


def kinds(store: StationStore, robot: str) -> list[tuple[str, str]]:
    page = store.events(robot, limit=1000)
    return sorted((e.kind, e.origin) for e in page.events)


class NewBox(Protocol):
    def __call__(self, robot: str, domain: int, *commands: str,
                 store: Path | None = None) -> ScriptedBlackBox: ...


@pytest.fixture
def new_box() -> Iterator[NewBox]:
    """Starts a scripted black box, sends it ``commands``; stops them all at the end."""
    started: list[ScriptedBlackBox] = []

    def start(robot: str, domain: int, *commands: str,
              store: Path | None = None) -> ScriptedBlackBox:
        box = ScriptedBlackBox(robot, domain, store=store)
        started.append(box)
        for command in commands:
            box.send(command)
        return box
    yield start
    for box in started:
        box.stop()


@pytest.fixture(autouse=True)
def _loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CYCLONEDDS_URI", raising=False)


def follower_for(store: StationStore, domain: int, **kwargs: Any) -> StationFollower:
    kwargs.setdefault("signer", station_signer_for_tests())
    follower = StationFollower(store, TransportSettings(domain), station_id="test-station",
                               **kwargs)
    follower.start()
    return follower


@contextmanager
def following(path: Path, domain: int,
              **kwargs: Any) -> Iterator[tuple[StationStore, StationFollower]]:
    """A station database at ``path`` and a follower of ``domain`` into it, for the block."""
    store = StationStore.open(path)
    follower = follower_for(store, domain, **kwargs)
    try:
        yield store, follower
    finally:
        follower.stop()
        store.close()


def period_series(store: StationStore) -> list[float]:
    chars = {c.name: c for c in store.characteristics("thesis")}
    period = chars.get("hz /usb_cam/image_raw [/usb_cam] period")
    return [] if period is None else [p.value for p in store.series("thesis",
                                                                    period.instance_id)]


def test_live_state_events_and_a_rectification_reach_the_station_database(
        tmp_path: Path, new_box: NewBox) -> None:
    domain = fresh_domain()
    box = new_box("thesis", domain, "ok")
    with following(tmp_path / "station.db", domain, backfill=0) as (store, _):
        wait(lambda: health(store, "thesis").get("/usb_cam") == "OPERATIONAL")
        box.send("fault")
        wait(lambda: ("failure", "live") in kinds(store, "thesis"))
        # the diagnosis is state on its own topic: it may land just after the event
        wait(lambda: store.diagnosis("thesis").components == ("/usb_cam",))
        # a characteristic is state (the latest sample per instance): the slow period must
        # have been taken before the next one replaces it in the reader
        wait(lambda: 0.5 in period_series(store))
        box.send("ok")  # the diagnosis no longer names the camera: a rectification
        wait(lambda: ("rectification", "live") in kinds(store, "thesis"))
        wait(lambda: store.diagnosis("thesis").components == ())
        assert kinds(store, "thesis") == [("diagnosis", "live"), ("diagnosis", "live"),
                                          ("exceedance", "live"), ("failure", "live"),
                                          ("rectification", "live")]
        failure = store.events("thesis", kinds=["failure"]).events[0]
        assert failure.entity == "/usb_cam"
        assert "camera publishes too slowly" in failure.text
        exceedance = store.events("thesis", kinds=["exceedance"]).events[0]
        assert exceedance.entity == "/usb_cam"
        assert exceedance.characteristic == "hz /usb_cam/image_raw [/usb_cam] period"
        assert store.diagnosis("thesis").components == ()
        chars = {c.name: c for c in store.characteristics("thesis")}
        period = chars["hz /usb_cam/image_raw [/usb_cam] period"]
        assert period.entity_name == "/usb_cam"
        wait(lambda: [p.value for p in store.series("thesis", period.instance_id)] == [
            0.0667, 0.5, 0.0667])
        chars = {c.name: c for c in store.characteristics("thesis")}
        assert chars["hz /usb_cam/image_raw [/usb_cam] period"].value == 0.0667
        code = chars["activated /usb_cam code"]
        assert [(t.type, t.value) for t in code.thresholds] == [("min", 0.0)]
        fleet = store.fleet()
        assert [(r.robot_id, r.online, r.stale) for r in fleet] == [("thesis", True, False)]
    db = sqlite3.connect(tmp_path / "station.db")
    assert db.execute("SELECT count(*) FROM events WHERE kind LIKE '%exceedence%'"
                      ).fetchone()[0] == 0
    db.close()


def test_a_restarted_station_rereads_state_and_backfills_exactly_what_it_missed(
        tmp_path: Path, new_box: NewBox) -> None:
    domain = fresh_domain()
    box = new_box("thesis", domain, "ok", store=tmp_path / "health.db")
    path = tmp_path / "station.db"
    with following(path, domain, backfill=600) as (store, follower):
        wait(lambda: health(store, "thesis").get("/usb_cam") == "OPERATIONAL")
        box.send("fault")
        wait(lambda: ("failure", "live") in kinds(store, "thesis"))
        wait(lambda: ("exceedance", "live") in kinds(store, "thesis"))
        wait(lambda: ("diagnosis", "live") in kinds(store, "thesis"))  # else it comes by log
    # While the station is down: the camera recovers and fails again.
    box.send("ok")
    box.send("fault")
    missed = [("diagnosis", "live"), ("diagnosis", "log"), ("diagnosis", "log"),
              ("exceedance", "live"), ("exceedance", "log"),
              ("failure", "live"), ("failure", "log"), ("rectification", "log")]
    with following(path, domain, backfill=600) as (store, follower):
        wait_until(lambda: kinds(store, "thesis") == missed,
                   "the backfill to store the two diagnoses, the exceedance, the failure and "
                   "the rectification of the robot's log beside what was heard live",
                   timeout=60, state=lambda: kinds(store, "thesis"))
        wait(lambda: health(store, "thesis")["/usb_cam"] == "NOT_OPERATIONAL")
        wait(lambda: store.diagnosis("thesis").components == ("/usb_cam",))
        assert follower.stats.backfilled >= 3
        assert kinds(store, "thesis") == missed, "nothing stored twice meanwhile"
        logged = sorted((e.time, e.details.get("components"))
                        for e in store.events("thesis", kinds=["diagnosis"]).events
                        if e.origin == "log")
        assert [components for _, components in logged] == [[], ["/usb_cam"]]


def test_log_requests_page_through_the_robots_own_log_and_download_it(
        tmp_path: Path, new_box: NewBox) -> None:
    domain = fresh_domain()
    health_db = tmp_path / "health.db"
    box = new_box("thesis", domain, store=health_db)
    start = time.time()
    for command in ("ok", "fault", "ok", "fault", "ok"):
        box.send(command)
    end = time.time()
    with following(tmp_path / "station.db", domain, backfill=0, log_page=4) as (store, follower):
        wait(lambda: health(store, "thesis"))

        def own_log(**query: Any) -> list[dict[str, Any]]:
            own = Store.open(str(health_db), readonly=True, check=False)
            try:
                return [e.to_dict() for e in own.query(start=start, end=end, **query)]
            finally:
                own.close()
        # The recorder commits in the background: wait until everything sent is there.
        wait(lambda: sum(e["kind"] == "diagnosis" for e in own_log()) == 5)
        everything = own_log()
        camera = own_log(entity="/usb_cam")
        assert len(everything) > 8  # several pages of 4

        request = follower.request_logs("thesis", since=start, until=end, requested_by="olga")
        done = wait(lambda: (r := store.log_request(request)) and r.status != "pending"
                    and r.status != "running" and r)
        assert (done.status, done.rows, done.progress) == ("done", len(everything), 1.0)
        assert done.pages >= len(everything) // 4
        assert [e.to_dict() for e in store.iter_log_entries(request)] == everything
        import io

        text = io.StringIO()
        store.export_log(request, "jsonl", text)
        assert [json.loads(line) for line in text.getvalue().splitlines()] == everything

        one = follower.request_logs("thesis", entity="/usb_cam", since=start, until=end)
        wait(lambda: store.log_request(one).status == "done")  # type: ignore[union-attr]
        assert [e.to_dict() for e in store.iter_log_entries(one)] == camera

        capped = follower.request_logs("thesis", since=start, until=end, max_rows=5)
        info = wait(lambda: (r := store.log_request(capped)) and r.status == "truncated" and r)
        assert info.rows == 5 and "narrow" in info.message

        with pytest.raises(ValueError, match="days"):
            follower.request_logs("thesis", since=0.0)
        with pytest.raises(ValueError, match="until is before since"):
            follower.request_logs("thesis", since=end, until=start)
        with pytest.raises(ValueError, match="unknown log kind"):
            follower.request_logs("thesis", kinds=["exceedence"])
        with pytest.raises(UnknownRobot):
            follower.request_logs("nobody")
        assert [e.kind for e in store.events("thesis", kinds=["log_request"]).events] == [
            "log_request"] * 3


def test_a_built_in_test_runs_and_its_result_is_stored(
        tmp_path: Path, new_box: NewBox) -> None:
    domain = fresh_domain()
    new_box("thesis", domain, "fault")
    with following(tmp_path / "station.db", domain, backfill=0) as (store, follower):
        wait(lambda: health(store, "thesis").get("/usb_cam"))
        run = follower.run_ibit("thesis", requested_by="olga")
        result = wait(lambda: (r := store.ibit_run(run)) and r.status != "pending" and r,
                      timeout=45)  # the robot's reply waits for matching both ways
        # A refusal ("unknown station", no observations) here came from another run's robot
        # of the same name on the same domain: tests/isolation.py keeps runs apart.
        assert (result.status, result.observations, result.failed) == ("done", 5, 0), \
            result.report
        assert result.report[0] == "OK hz /usb_cam/image_raw [/usb_cam] GENERAL_OK"
        [event] = store.events("thesis", kinds=["ibit"]).events
        assert "0 of 5 checks failed" in event.text
        with pytest.raises(UnknownRobot):
            follower.run_ibit("thesis", entity="/no_such_node")


def _udp_ports(pid: int) -> list[int]:
    return sorted({c.laddr.port for c in psutil.Process(pid).net_connections(kind="udp")})


def test_unknown_robots_spoofed_oversized_and_garbage_input_are_reported_and_survived(
        tmp_path: Path, new_box: NewBox) -> None:
    domain = fresh_domain()
    box = new_box("thesis", domain, "ok")
    store = StationStore.open(tmp_path / "station.db")
    follower = StationFollower(store, TransportSettings(domain), backfill=0,
                               signer=station_signer_for_tests())
    follower.identify_within = 1.0
    follower.start()
    try:
        wait(lambda: health(store, "thesis").get("/usb_cam") == "OPERATIONAL")
        intruder = subprocess.run([sys.executable, str(HERE / "station_intruder.py"),
                                   str(domain), "thesis"], capture_output=True, text=True,
                                  env=dds_env(), timeout=60)
        assert intruder.returncode == 0, intruder.stderr
        ports = _udp_ports(os.getpid())
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for port in ports:
                for payload in (b"", b"RTPS\x02\x01", os.urandom(300), b"RTPS" + os.urandom(60)):
                    s.sendto(payload, ("127.0.0.1", port))
        box.send("fault")
        wait(lambda: health(store, "thesis").get("/usb_cam") == "NOT_OPERATIONAL")

        def problem(text: str) -> bool:
            return any(text in p.message for p in store.problems(200))
        wait(lambda: problem("resource id 12345"))
        assert problem("claims robot id 'thesis'")
        assert problem("clipped")
        assert [r.robot_id for r in store.fleet()] == ["thesis"]  # no stranger, no spoof
        names = [e.name for e in store.entities("thesis")]
        assert max(len(n) for n in names) <= 200
        long_failure = [e for e in store.events("thesis", kinds=["failure"]).events
                        if e.text.startswith("ddd")]
        assert long_failure and len(long_failure[0].text) <= 2000
        assert follower._threads and all(t.is_alive() for t in follower._threads)
    finally:
        follower.stop()
        store.close()


@pytest.fixture(params=FULL_DISK_VARIANTS)
def full_disk(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Any]:
    with full_disk_in(request.param, tmp_path) as disk:
        yield disk


def test_a_full_station_disk_is_reported_and_nothing_heard_meanwhile_is_lost(
        full_disk: Any, new_box: NewBox) -> None:
    domain = fresh_domain()
    box = new_box("thesis", domain, "ok")
    with following(full_disk.directory / "station.db", domain, backfill=0) as (store, follower):
        wait(lambda: health(store, "thesis").get("/usb_cam") == "OPERATIONAL")
        full_disk.fill(store)
        for _ in range(20):  # more than fits in the last free pages
            box.send("fault")
            box.send("ok")
        wait(lambda: any("cannot write" in p.message for p in store.problems()))
        assert health(store, "thesis")  # what was stored can still be read
        assert follower._threads and all(t.is_alive() for t in follower._threads)
        full_disk.free(store)
        try:
            wait(lambda: store.count_events("thesis", kinds=["failure"]) == 20
                 and store.count_events("thesis", kinds=["rectification"]) == 20, timeout=20)
        except AssertionError:
            raise AssertionError((store.count_events("thesis", kinds=["failure"]),
                                  store.count_events("thesis", kinds=["rectification"]),
                                  store.pending, store.problems())) from None
        # nothing more is queued to write, and what is stored has no copy
        wait(lambda: store.pending == 0, timeout=20)
        assert store.count_events("thesis", kinds=["failure", "rectification"]) == 40


def test_the_simulated_robot_run_by_blackbox_run_feeds_the_station(tmp_path: Path) -> None:
    domain = fresh_domain()
    faults = tmp_path / "faults.yaml"
    faults.write_text("faults:\n  - {kind: kill, component: /usb_cam, start: 3, end: 8}\n")
    record = tmp_path / "bb.db"
    box = subprocess.Popen([sys.executable, "-m", "blackbox", "run", "--dds", "--domain",
                            str(domain), "--quiet", "--config", str(trusting_thesis_config()),
                            "--faults", str(faults), "--record", str(record), "--duration", "40"],
                           env=dds_env(),
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    store = StationStore.open(tmp_path / "station.db")
    follower = follower_for(store, domain, backfill=0)
    try:
        wait(lambda: ("failure", "live") in kinds(store, "thesis-robot"), timeout=30)
        failure = store.events("thesis-robot", kinds=["failure"]).events[-1]
        assert failure.entity == "/usb_cam"
        wait(lambda: ("rectification", "live") in kinds(store, "thesis-robot"), timeout=30)
        tree = {e.name: e for e in store.entities("thesis-robot")}
        assert {"/usb_cam", "/audio_capture", "/Signal_generator"} <= set(tree)
        assert store.characteristics("thesis-robot", tree["/usb_cam"].instance_id)

        def recorded(until: float | None = None) -> list[dict[str, Any]]:
            own = Store.open(str(record), readonly=True, check=False)
            try:
                return [e.to_dict() for e in own.query(kinds=["failure"], end=until)]
            finally:
                own.close()
        # The robot's recorder commits every second: wait until it holds the rectification.
        wait(lambda: len(recorded()) >= 2, timeout=10)
        until = time.time()
        request = follower.request_logs("thesis-robot", kinds=["failure"], until=until)
        info = wait(lambda: (r := store.log_request(request)) and r.status not in
                    ("pending", "running") and r, timeout=30)
        assert info.status == "done", info.message
        fetched = [e.to_dict() for e in store.iter_log_entries(request)]
        assert fetched == recorded(until)
        assert [e["payload"]["category"] for e in fetched][:2] == ["detection",
                                                                   "rectification"]
    finally:
        follower.stop()
        store.close()
        box.send_signal(signal.SIGINT)
        try:
            box.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            box.kill()


def test_an_operators_log_request_does_not_wait_behind_a_stuck_backfill(
        tmp_path: Path, new_box: NewBox) -> None:
    domain = fresh_domain()
    new_box("mute", domain, "ok")  # no recorder: its log requests go unanswered
    with following(tmp_path / "station.db", domain, backfill=600) as (store, follower):
        wait(lambda: follower._backfills.lock.locked())  # the mute robot's backfill waits
        new_box("thesis", domain, "fault", store=tmp_path / "health.db")
        wait(lambda: health(store, "thesis"))
        request = follower.request_logs("thesis", kinds=["failure"])
        info = wait(lambda: (r := store.log_request(request)) and r.status == "done" and r)
        assert info.rows == 1
        assert not any("mute" in p.message for p in store.problems(200))  # still waiting
        wait(lambda: any("mute: missed events not fetched" in p.message
                         for p in store.problems(200)), timeout=30)
