"""A robot started while its Zenoh router is down keeps running and recording, and delivers
everything, in order, once the router appears (``blackbox run --zenoh`` as an operator
starts it, in its own process; a real Zenoh router and the station follower in this one:
the router starts in milliseconds, so the robot is still running when it appears)."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from blackbox.record import Store
from blackbox.station.follow import StationFollower
from blackbox.station.store import StationStore
from blackbox.transport.participant import TransportSettings
from blackbox.transport.zenoh_bus import ZenohSettings
from blackbox.transport.zenoh_router import RouterSettings, open_router
from conftest import wait_until
from station_support import dds_env, station_signer_for_tests
from zenoh_support import free_tcp_port

pytestmark = pytest.mark.dds

ROUTER_AFTER = 12.0
"""Seconds the robot runs before its router exists: longer than a Zenoh client waits."""


def recorded_events(path: Path) -> list[str]:
    """The identities of the failures and rectifications the robot recorded, in order."""
    own = Store.open(str(path), readonly=True, check=False)
    try:
        return [f"id:{e['id']}" for entry in own.query(kinds=["failure"])
                if isinstance(entry.payload, dict)
                for e in entry.payload.get("events") or []]
    finally:
        own.close()


def stored_events(path: Path) -> list[str]:
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return [d for (d,) in db.execute("SELECT dedup FROM events WHERE kind IN "
                                         "('failure', 'rectification') ORDER BY time, id")]
    finally:
        db.close()


def test_a_robot_started_before_its_router_runs_records_and_delivers_everything_in_order(
        tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    faults = tmp_path / "faults.yaml"
    faults.write_text("faults:\n  - {kind: kill, component: /usb_cam, start: 2, end: 5}\n"
                      "  - {kind: kill, component: /usb_cam, start: 22, end: 25}\n")
    record = tmp_path / "bb.db"
    started = time.monotonic()
    robot = subprocess.Popen(
        [sys.executable, "-m", "blackbox", "run", "--zenoh", endpoint, "--quiet",
         "--faults", str(faults), "--record", str(record), "--duration", "45"],
        env=dds_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    router: Any = None
    store = StationStore.open(tmp_path / "station.db", stale_after=5.0)
    follower: StationFollower | None = None
    try:
        wait_until(lambda: robot.poll() is not None or (
            time.monotonic() - started > ROUTER_AFTER and record.exists()
            and len(recorded_events(record)) >= 1),
            f"the robot to run {ROUTER_AFTER:g} s without a router and record a failure",
            timeout=90)
        assert robot.poll() is None, f"the robot stopped without its router: " \
                                     f"{robot.communicate()[1][-2000:]}"
        before = recorded_events(record)
        router = open_router(RouterSettings((endpoint,)))
        follower = StationFollower(
            store, TransportSettings(zenoh=ZenohSettings((endpoint,))),
            station_id="test-station", signer=station_signer_for_tests(), backfill=600)
        follower.start()
        wait_until(lambda: set(before) <= set(stored_events(tmp_path / "station.db")),
                   f"what the robot recorded before the router existed ({before}), at the "
                   "station", timeout=60)
        _, err = robot.communicate(timeout=90)
        assert robot.returncode == 0, err[-2000:]
        assert "Traceback" not in err, err
        everything = recorded_events(record)
        assert len(everything) >= 4 and len(everything) > len(before), \
            f"two faults, each a failure and a rectification, some after the router came: " \
            f"{before} then {everything}"
        wait_until(lambda: len(stored_events(tmp_path / "station.db")) >= len(everything),
                   f"the {len(everything)} failures and rectifications the robot recorded, "
                   "at the station", timeout=60)
        assert stored_events(tmp_path / "station.db") == everything, \
            "the station holds exactly what the robot recorded, in the robot's order"
    finally:
        if robot.poll() is None:
            robot.send_signal(signal.SIGINT)
            try:
                robot.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                robot.kill()
                robot.communicate()
        if follower is not None:
            follower.stop()
        store.close()
        if router is not None:
            router.close()
