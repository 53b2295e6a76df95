"""The station tells the operator when the bus drops samples before it could take them, or
when it cannot keep up with the fleet: a problem on every page and figures in /metrics.
The drops are real: a Zenoh reader with a small queue behind a real in-process router."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.extension import C_Entity_Description
from blackbox.health.types import T_IdentifierType
from blackbox.station.delivery import BEHIND_AFTER, DeliveryWatch
from blackbox.station.store import StationStore
from blackbox.station.web.metrics import station_metrics
from blackbox.transport import zenoh_bus
from blackbox.transport.zenoh_bus import ZenohBus, ZenohSettings
from blackbox.transport.zenoh_router import RouterSettings, open_router
from conftest import wait_until
from zenoh_support import free_tcp_port

TOPIC = "BlackBox_Entity_Description"


@pytest.fixture
def store(tmp_path: Path) -> Iterator[StationStore]:
    s = StationStore.open(tmp_path / "station.db")
    yield s
    s.close()


def watch_of(store: StationStore) -> DeliveryWatch:
    return DeliveryWatch(store.report_problem, store.clear_problem)


def problems(store: StationStore) -> dict[str, str]:
    return {p.source: p.message for p in store.problems()}


def test_samples_the_bus_dropped_are_a_problem_and_a_metric(
        store: StationStore, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(zenoh_bus, "READER_DEPTH", 10)  # a station that takes too rarely
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    router: Any = open_router(RouterSettings((endpoint,)))
    station = ZenohBus.open(ZenohSettings((endpoint,)), "station")
    robot = ZenohBus.open(ZenohSettings((endpoint,)), "thesis")
    try:
        reader = station.reader(TOPIC)
        writer = robot.writer(TOPIC)
        watch = watch_of(store)
        watch.check({TOPIC: reader}, now=0.0)
        assert "delivery" not in problems(store), "nothing dropped yet, nothing said"

        sent = 0

        def sent_until_dropped() -> bool:
            nonlocal sent
            for i in range(10):
                writer.write(C_Entity_Description(
                    A_sourceID=T_IdentifierType(1, 2 + i), A_robotId="thesis",
                    A_name=f"/node{i}", A_kind="node", A_parent_sourceID=T_IdentifierType(1, 1)))
                sent += 1
            return reader.overflowed >= 15
        wait_until(sent_until_dropped, "15 samples dropped by the reader's full queue")
        # every sample sent is queued or counted as dropped before the watch looks
        wait_until(lambda: reader.overflowed + reader.pull() >= sent,
                   "the rest of the samples sent to reach the reader")
        watch.check({TOPIC: reader}, now=10.0)
        dropped = reader.overflowed
        message = problems(store)["delivery"]
        assert message.startswith(f"{dropped} samples dropped by the bus before the station "
                                  f"could take them (most on {TOPIC})"), message
        assert f"blackbox_station_samples_dropped_total {dropped}" in \
            station_metrics(store, None, watch)
        assert len([p for p in store.problems() if p.source == "delivery"]) == 1
    finally:
        robot.close()
        station.close()
        router.close()


def test_a_station_that_cannot_keep_up_says_so_and_says_when_it_caught_up(
        store: StationStore) -> None:
    watch = watch_of(store)
    t = 100.0
    while t < 100.0 + BEHIND_AFTER - 0.5:  # full takes for less than BEHIND_AFTER: silent
        watch.took(True, t, 0.5)
        t += 0.5
    assert "ingest" not in problems(store)
    watch.took(True, 100.0 + BEHIND_AFTER, 0.5)
    assert problems(store)["ingest"].startswith("the station cannot keep up: samples have "
                                                f"been waiting for {BEHIND_AFTER:.0f} s")
    assert "blackbox_station_ingest_behind 1" in station_metrics(store, None, watch)
    watch.took(False, 100.0 + BEHIND_AFTER + 1, 0.1)
    assert "ingest" not in problems(store)
    assert problems(store)["ingest-recovered"] == "the station keeps up with the fleet again"
    assert "blackbox_station_ingest_behind 0" in station_metrics(store, None, watch)
