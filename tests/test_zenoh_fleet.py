"""Robots reach a station across networks over Zenoh: a real router (``blackbox router``)
on loopback in its own process, a scripted black box in another, the station follower in
this one. The link is cut by killing the router and restored by starting it again; every
event is counted by its identity. TLS uses a throwaway CA made by the test."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.record import Store
from blackbox.station.follow import StationFollower
from blackbox.station.store import StationStore, UnknownRobot
from blackbox.transport.participant import TransportSettings
from blackbox.transport.zenoh_bus import ZenohBus, ZenohError, ZenohSettings
from conftest import wait_until
from station_support import ScriptedBlackBox, dds_env, station_signer_for_tests
from throwaway_ca import make_ca_and_server
from zenoh_support import RouterProcess, free_tcp_port

pytestmark = pytest.mark.dds

STALE_AFTER = 5.0
"""Seconds unheard before a robot shows UNKNOWN. 2 s was shorter than the time a loaded
machine (load average 40) took from the robot's state arriving to the station's store
showing it, so the robot was stale again before the test could see it known."""


def event_counts(path: Path) -> dict[str, int]:
    """Failures and rectifications stored, with how many distinct identities they have."""
    db = sqlite3.connect(path)
    try:
        rows = db.execute("SELECT kind, count(*), count(DISTINCT dedup) FROM events "
                          "WHERE kind IN ('failure', 'rectification') GROUP BY kind").fetchall()
    finally:
        db.close()
    out = {kind: n for kind, n, _ in rows}
    out["distinct"] = sum(d for _, _, d in rows)
    return out


def usb_cam(store: StationStore) -> str | None:
    try:
        return {e.name: e.reported_status for e in store.entities("thesis")}.get("/usb_cam")
    except UnknownRobot:
        return None


@pytest.fixture
def router_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_tcp_port()}"


@pytest.fixture
def cleanup() -> Iterator[list[RouterProcess | ScriptedBlackBox]]:
    started: list[RouterProcess | ScriptedBlackBox] = []
    yield started
    for thing in reversed(started):
        if isinstance(thing, RouterProcess):
            thing.kill()
        else:
            thing.stop()


def test_events_sent_while_the_router_was_down_arrive_once_when_it_returns(
        tmp_path: Path, router_endpoint: str,
        cleanup: list[RouterProcess | ScriptedBlackBox]) -> None:
    router = RouterProcess(router_endpoint)
    cleanup.append(router)
    box = ScriptedBlackBox("thesis", 0, store=tmp_path / "health.db", zenoh=router_endpoint)
    cleanup.append(box)
    store = StationStore.open(tmp_path / "station.db", stale_after=STALE_AFTER)
    follower = StationFollower(
        store, TransportSettings(zenoh=ZenohSettings((router_endpoint,))),
        station_id="test-station", signer=station_signer_for_tests(), backfill=600)
    follower.start()
    try:
        box.send("ok")
        wait_until(lambda: usb_cam(store) == "OPERATIONAL", "the camera healthy over Zenoh",
                   timeout=30)
        box.send("burst 50")
        wait_until(lambda: event_counts(tmp_path / "station.db").get("distinct") == 100,
                   "50 failures and 50 rectifications over Zenoh", timeout=30)

        router.kill()  # the link is cut: the robot goes on failing and recovering
        box.send("burst 200")
        box.send("fault")  # its last word before the link returns: the camera is failing
        statuses = []
        deadline = time.monotonic() + STALE_AFTER + 2.0
        while time.monotonic() < deadline:
            statuses.append(store.fleet()[0].status)
            time.sleep(0.1)
        assert statuses[-1] == "UNKNOWN", "a robot not heard from is shown UNKNOWN"
        assert "OPERATIONAL" not in statuses[-10:], "never healthy while unheard"
        assert event_counts(tmp_path / "station.db")["distinct"] == 100, \
            "nothing passed the dead router"

        cleanup.append(RouterProcess(router_endpoint))  # the link returns
        # The robot is heard again: its last state, and it is no longer UNKNOWN. Checked as
        # it arrives: this scripted robot is silent afterwards, so it turns stale again
        # STALE_AFTER later (the backfill below took longer than that on a loaded machine).
        wait_until(lambda: usb_cam(store) == "NOT_OPERATIONAL"
                   and store.fleet()[0].status != "UNKNOWN",
                   "the camera's last state, heard again after the link returned", timeout=60)
        wait_until(lambda: event_counts(tmp_path / "station.db").get("distinct") == 501,
                   "251 failures and 250 rectifications after the link returned",
                   timeout=60)
        time.sleep(1.0)  # what a duplicate would need to arrive, were there one
        counts = event_counts(tmp_path / "station.db")
        assert counts == {"failure": 251, "rectification": 250, "distinct": 501}
        assert usb_cam(store) == "NOT_OPERATIONAL"
        db = sqlite3.connect(tmp_path / "station.db")
        origins = dict(db.execute("SELECT origin, count(*) FROM events WHERE kind IN "
                                  "('failure', 'rectification') GROUP BY origin").fetchall())
        times = [t for (t,) in db.execute("SELECT time FROM events WHERE kind = 'failure' "
                                          "ORDER BY id")]
        db.close()
        print(f"origins {origins}")
        assert times == sorted(times), "failures stored in the order the robot made them"
    finally:
        follower.stop()
        store.close()


def test_over_tls_health_signed_log_requests_and_built_in_tests_reach_the_robot(
        tmp_path: Path, cleanup: list[RouterProcess | ScriptedBlackBox]) -> None:
    tls = make_ca_and_server(tmp_path / "tls")
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    cleanup.append(RouterProcess(endpoint, ["--zenoh-certificate", str(tls.certificate),
                                            "--zenoh-key", str(tls.private_key)]))
    health_db = tmp_path / "health.db"
    box = ScriptedBlackBox("thesis", 0, store=health_db, zenoh=endpoint, tls_ca=tls.ca)
    cleanup.append(box)
    start = time.time()
    for command in ("ok", "fault", "ok"):
        box.send(command)
    end = time.time()
    store = StationStore.open(tmp_path / "station.db")
    follower = StationFollower(
        store, TransportSettings(zenoh=ZenohSettings((endpoint,), root_ca=str(tls.ca))),
        station_id="test-station", signer=station_signer_for_tests(), backfill=0)
    follower.start()
    try:
        # the robot spoke before the station came: the robot's cache gives it all
        wait_until(lambda: event_counts(tmp_path / "station.db") == {
            "failure": 1, "rectification": 1, "distinct": 2},
            "the failure and rectification made before the station came", timeout=30)
        assert usb_cam(store) is not None

        own = Store.open(str(health_db), readonly=True, check=False)
        try:
            logged = [e.to_dict() for e in own.query(start=start, end=end)]
        finally:
            own.close()
        request = follower.request_logs("thesis", since=start, until=end, requested_by="olga")
        done = wait_until(lambda: (r := store.log_request(request)) and r.status not in (
            "pending", "running") and r, "the signed log request's answer", timeout=30)
        assert (done.status, done.rows) == ("done", len(logged))  # type: ignore[union-attr]
        assert [e.to_dict() for e in store.iter_log_entries(request)] == logged

        run = follower.run_ibit("thesis", requested_by="olga")
        result = wait_until(lambda: (r := store.ibit_run(run)) and r.status != "pending" and r,
                            "the built-in test's result", timeout=30)
        assert (result.status, result.observations, result.failed) == (  # type: ignore[union-attr]
            "done", 5, 0)
    finally:
        follower.stop()
        store.close()


def test_a_station_that_does_not_trust_the_routers_certificate_stops_with_one_line(
        tmp_path: Path, cleanup: list[RouterProcess | ScriptedBlackBox]) -> None:
    tls = make_ca_and_server(tmp_path / "tls")
    stranger = make_ca_and_server(tmp_path / "other", "another CA")
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    cleanup.append(RouterProcess(endpoint, ["--zenoh-certificate", str(tls.certificate),
                                            "--zenoh-key", str(tls.private_key)]))
    with pytest.raises(ZenohError, match=f"cannot open a Zenoh session to {endpoint}"):
        ZenohBus.open(ZenohSettings((endpoint,), root_ca=str(stranger.ca)), "station")


def test_blackbox_run_and_blackbox_station_meet_through_a_router(
        tmp_path: Path, router_endpoint: str,
        cleanup: list[RouterProcess | ScriptedBlackBox]) -> None:
    """The commands of docs/station.md, Fleet deployment: a simulated robot whose camera
    node dies at 3 s, a station serving the web pages, both only knowing the router."""
    cleanup.append(RouterProcess(router_endpoint))
    faults = tmp_path / "faults.yaml"
    faults.write_text("faults:\n  - {kind: kill, component: /usb_cam, start: 3, end: 8}\n")
    ready = tmp_path / "station.url"
    station_db = tmp_path / "station.db"
    station = subprocess.Popen(
        [sys.executable, "-m", "blackbox", "station", "--db", str(station_db), "--bind",
         "127.0.0.1:0", "--zenoh", router_endpoint, "--ready-file", str(ready),
         "--duration", "90"], env=dds_env(), stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True)
    robot = subprocess.Popen(
        [sys.executable, "-m", "blackbox", "run", "--zenoh", router_endpoint, "--quiet",
         "--faults", str(faults), "--record", str(tmp_path / "bb.db"), "--duration", "40"],
        env=dds_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(ready.exists, "the station to serve", timeout=60)
        wait_until(lambda: event_counts(station_db).get("failure", 0) >= 1
                   and event_counts(station_db).get("rectification", 0) >= 1,
                   "the camera's failure and rectification at the station", timeout=60)
        db = sqlite3.connect(f"file:{station_db}?mode=ro", uri=True)
        try:
            [(entity,)] = db.execute("SELECT entity FROM events WHERE kind = 'failure' "
                                     "LIMIT 1").fetchall()
        finally:
            db.close()
        assert entity == "/usb_cam"
    finally:
        for proc in (robot, station):
            proc.send_signal(signal.SIGINT)
        for proc in (robot, station):
            try:
                _, err = proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                _, err = proc.communicate()
            assert "Traceback" not in err, err


def test_a_robot_and_a_station_at_two_sites_meet_through_two_routers(
        tmp_path: Path, cleanup: list[RouterProcess | ScriptedBlackBox]) -> None:
    robot_site = f"tcp/127.0.0.1:{free_tcp_port()}"
    station_site = f"tcp/127.0.0.1:{free_tcp_port()}"
    cleanup.append(RouterProcess(station_site))
    cleanup.append(RouterProcess(robot_site, ["--connect", station_site]))
    box = ScriptedBlackBox("thesis", 0, store=tmp_path / "health.db", zenoh=robot_site)
    cleanup.append(box)
    store = StationStore.open(tmp_path / "station.db")
    follower = StationFollower(
        store, TransportSettings(zenoh=ZenohSettings((station_site,))),
        station_id="test-station", signer=station_signer_for_tests(), backfill=0)
    follower.start()
    try:
        box.send("ok")
        wait_until(lambda: usb_cam(store) == "OPERATIONAL",
                   "the camera's state across two routers", timeout=30)
        box.send("burst 100")
        wait_until(lambda: event_counts(tmp_path / "station.db").get("distinct") == 200,
                   "100 failures and 100 rectifications across two routers", timeout=60)
        assert event_counts(tmp_path / "station.db") == {
            "failure": 100, "rectification": 100, "distinct": 200}
    finally:
        follower.stop()
        store.close()
