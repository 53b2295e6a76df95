"""Robots reach a station across networks over Zenoh: a real router (``blackbox router``)
on loopback in its own process, a scripted black box in another, the station follower in
this one. The link is cut by killing the router and restored by starting it again; every
event is counted by its identity."""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.station.follow import StationFollower
from blackbox.station.store import StationStore, UnknownRobot
from blackbox.transport.participant import TransportSettings
from blackbox.transport.zenoh_bus import ZenohSettings
from conftest import wait_until
from station_support import ScriptedBlackBox, station_signer_for_tests
from zenoh_support import RouterProcess, free_tcp_port

pytestmark = pytest.mark.dds

STALE_AFTER = 2.0


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
        wait_until(lambda: event_counts(tmp_path / "station.db").get("distinct") == 501,
                   "251 failures and 250 rectifications after the link returned",
                   timeout=60)
        time.sleep(1.0)  # what a duplicate would need to arrive, were there one
        counts = event_counts(tmp_path / "station.db")
        assert counts == {"failure": 251, "rectification": 250, "distinct": 501}
        wait_until(lambda: usb_cam(store) == "NOT_OPERATIONAL",
                   "the camera's last state after the link returned")
        assert store.fleet()[0].status != "UNKNOWN"
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
