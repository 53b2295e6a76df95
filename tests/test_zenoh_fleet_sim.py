"""The lightweight simulated robot (``benchmarks/fleet_sim.py``: many robots on one Zenoh
session, as the fleet benchmark runs 1,000 of them) publishes what a real black box
publishes for the same health: the same bytes under the same key expressions, and a real
station stores the same rows from it.

A real black box (``DdsHealthSink`` with its own Zenoh session) and a lightweight robot of
the same id, clock and boot get the same thesis-robot health (a camera fault that is
diagnosed and ends). Each publishes in a partition of its own through one real in-process
Zenoh router; a raw Zenoh tap records every payload per key, and one real station per
partition (follower + SQLite store) ingests them.
"""

from __future__ import annotations

import importlib.util
import sqlite3
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
import zenoh.ext as zext

from blackbox.health.identity import EventLedger
from blackbox.model import Diagnosis
from blackbox.station.follow import StationFollower
from blackbox.station.store import StationStore
from blackbox.transport.participant import TransportSettings
from blackbox.transport.publisher import DdsHealthSink
from blackbox.transport.zenoh_bus import ZenohSettings
from blackbox.transport.zenoh_router import RouterSettings, open_router
from conftest import wait_for, wait_until
from zenoh_support import free_tcp_port


def _load_fleet_sim() -> Any:
    """``benchmarks/fleet_sim.py`` by its path (the benchmarks directory is not put on
    ``sys.path``: its modules' names would shadow others for the whole test process)."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "fleet_sim.py"
    spec = importlib.util.spec_from_file_location("fleet_sim", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["fleet_sim"] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


fleet_sim = _load_fleet_sim()
LightFleet = fleet_sim.LightFleet
thesis_observations = fleet_sim.thesis_observations

pytestmark = pytest.mark.dds

BOOT = "00c0ffee00c0ffee"
TICKS = 16
FAULTY = range(5, 11)
"""Ticks during which the camera is too slow: an exceedance, a failure, a rectification."""


class Tap:
    """Every payload a robot published under ``<partition>/**``, per key, in publication
    order, read from the publishers' caches once publishing is over.

    Why not a tap that listens while the robots publish: Zenoh's advanced subscriber
    delivers the first live sample of a publisher it has not met yet at once, and then
    drops that publisher's older samples when its history reply brings them (they look
    like duplicates). A tap declared after the last put sees no live sample, so its
    initial history query brings every cached sample, in order."""

    def __init__(self, session: zenoh.Session, partition: str) -> None:
        self.payloads: dict[str, list[bytes]] = {}
        self._lock = threading.Lock()
        self._subscriber = zext.declare_advanced_subscriber(
            session, f"{partition}/**", self._on_sample,
            history=zext.HistoryConfig(detect_late_publishers=False))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.payloads.setdefault(str(sample.key_expr), []).append(
                sample.payload.to_bytes())

    def count(self) -> int:
        with self._lock:
            return sum(len(v) for v in self.payloads.values())

    def by_topic(self) -> dict[str, list[bytes]]:
        """Payloads keyed by ``<origin>/<topic>`` (the partition left out)."""
        with self._lock:
            return {key.split("/", 1)[1]: list(v) for key, v in self.payloads.items()}

    def close(self) -> None:
        self._subscriber.undeclare()


def read_caches(session: zenoh.Session, partition: str, expected: int,
                timeout: float = 60.0) -> dict[str, list[bytes]]:
    """What the publishers in ``partition`` cached, by topic, once a tap has read all
    ``expected`` samples. A history query that reached the router before a publisher's
    cache was declared there is answered without it, so a tap that falls short is
    replaced by a new one (bounded by ``timeout``)."""
    deadline = time.monotonic() + timeout
    seen: dict[str, int] = {}
    while time.monotonic() < deadline:
        tap = Tap(session, partition)
        try:
            if wait_for(lambda t=tap: t.count() >= expected,  # type: ignore[misc]
                        min(10.0, max(0.0, deadline - time.monotonic()))):
                return tap.by_topic()
            seen = {k: len(v) for k, v in tap.by_topic().items()}
        finally:
            tap.close()
    raise AssertionError(f"waited {timeout:g} s for the caches of {partition!r} to give "
                         f"{expected} samples; the last tap read {seen}")


def drive_real_robot(sink: DdsHealthSink, t0: float) -> None:
    """What the fleet benchmark's robots do, written out for a real black box."""
    faulty = False
    for k in range(TICKS):
        t = t0 + k
        now_faulty = k in FAULTY
        observations = thesis_observations(t, now_faulty)
        sink.on_observations(t, observations)
        if now_faulty and not faulty:
            sink.on_diagnosis(Diagnosis(t, (frozenset({"/usb_cam"}),), (observations[0],),
                                        "camera publishes too slowly"))
        elif faulty and not now_faulty:
            sink.on_diagnosis(Diagnosis(t, ()))
        faulty = now_faulty


def stored_rows(path: Path) -> dict[str, list[tuple[Any, ...]]]:
    """What a station stored for its one robot: every characteristic value, and every
    event the robot numbered (kind, identity, robot, time). The station's own wording and
    its ``diagnosis`` rows are left out: they depend on which topic's sample it took first
    (a rectification taken before the entity's description names the entity by its id),
    timing on the station, not what the robot sent."""
    db = sqlite3.connect(path)
    try:
        return {
            "samples": db.execute("SELECT resource_id, characteristic, time, value FROM "
                                  "samples ORDER BY characteristic, time").fetchall(),
            "events": db.execute("SELECT resource_id, time, kind, dedup FROM events "
                                 "WHERE origin = 'live' AND kind != 'diagnosis' "
                                 "ORDER BY time, kind, dedup").fetchall(),
        }
    finally:
        db.close()


@pytest.fixture
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    session = open_router(RouterSettings((endpoint,)))
    try:
        yield endpoint
    finally:
        session.close()


@pytest.mark.xdist_group("zenoh-fleet-sim")
def test_a_lightweight_robot_publishes_the_bytes_of_a_real_one_and_a_station_stores_the_same(
        router: str, tmp_path: Path) -> None:
    t0 = time.time() - TICKS - 5  # within the station's clock limit for every tick
    tap_session = zenoh.open(ZenohSettings((router,)).config())
    stations = {}
    for partition in ("real", "light"):
        store = StationStore.open(tmp_path / f"{partition}.db")
        follower = StationFollower(store, TransportSettings(
            0, zenoh=ZenohSettings((router,), partition=partition)), backfill=0)
        follower.start()
        stations[partition] = (store, follower)
    real = DdsHealthSink("twin", zenoh=ZenohSettings((router,), partition="real"),
                         clock=lambda: t0, ledger=EventLedger(BOOT))
    fleet = LightFleet(ZenohSettings((router,), partition="light"), ["twin"],
                       clock=lambda: t0, boot=BOOT)
    try:
        drive_real_robot(real, t0)
        light = fleet.robots[0]
        for k in range(TICKS):
            light.tick(t0 + k, k in FAULTY, watched=False)
        assert light.sink.counts == {"values": 11 * TICKS, "exceedances": 1, "failures": 1,
                                     "rectifications": 1}
        assert light.sink.written == real.written
        wait_until(fleet.connected, "the lightweight robot's session to reach the router")
        real_bytes = read_caches(tap_session, "real", real.written)
        light_bytes = read_caches(tap_session, "light", light.sink.written)
        assert sorted(light_bytes) == sorted(real_bytes)  # same keys: twin/<topic>
        for key, payloads in real_bytes.items():
            assert light_bytes[key] == payloads, f"{key}: different bytes"

        def both_stored() -> bool:
            rows = {p: stored_rows(tmp_path / f"{p}.db") for p in stations}
            return all(len(r["samples"]) == 11 * TICKS and len(r["events"]) == 3
                       for r in rows.values())

        wait_until(both_stored, "both stations to store every value and the three events",
                   timeout=60)
        real_rows, light_rows = (stored_rows(tmp_path / f"{p}.db") for p in ("real", "light"))
        assert light_rows == real_rows
        # the fault's exceedance, failure and rectification, each under its event identity
        # (the station's diagnosis rows beside them are keyed by time)
        identities = sorted((row[2], row[3]) for row in light_rows["events"])
        assert identities == [("exceedance", f"id:{BOOT}-1"), ("failure", f"id:{BOOT}-2"),
                              ("rectification", f"id:{BOOT}-3")]
    finally:
        fleet.close()
        real.close()
        for store, follower in stations.values():
            follower.stop()
            store.close()
        tap_session.close()  # type: ignore[no-untyped-call]
