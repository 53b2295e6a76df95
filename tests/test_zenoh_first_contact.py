"""A station that meets a robot's publisher through a live sample still gets what that
publisher published before: nothing a robot cached is lost at first contact.

Zenoh's advanced subscriber delivers the first live sample of a publisher it has not met
at once, and afterwards drops that publisher's older samples as duplicates when a history
or heartbeat reply brings them. So when the route from a robot to a station appears while
the robot is publishing, the samples the robot cached meanwhile were lost. Here the robot
and the station sit behind two routers that are not linked; the robot publishes into its
cache; a third router then links the two, and the robot publishes once more the moment its
samples can reach the station. The station must read every sample, in the order written.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack
from typing import Any

import pytest

from blackbox.health.types import C_Monitored_Characteristic, T_IdentifierType
from blackbox.transport.zenoh_bus import ZenohBus, ZenohReader, ZenohSettings
from blackbox.transport.zenoh_router import RouterSettings, open_router
from conftest import wait_until
from zenoh_support import free_tcp_port

CACHED = 40
"""Samples the robot publishes while no route reaches the station."""
LIVE = 5
PERIOD = 0.01
"""Seconds between two samples of the robot while the link appears."""
LINK_WAIT = 30.0


def _value(k: int) -> C_Monitored_Characteristic:
    return C_Monitored_Characteristic(A_sourceID=T_IdentifierType(7, 100 + k), A_value=float(k))


def _router(stack: ExitStack, connect: tuple[str, ...] = ()) -> str:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    session: Any = open_router(RouterSettings((endpoint,), connect))
    stack.callback(session.close)
    return endpoint


def _bus(stack: ExitStack, endpoint: str, origin: str) -> ZenohBus:
    bus = ZenohBus.open(ZenohSettings((endpoint,), partition="first"), origin)
    stack.callback(bus.close)
    return bus


@pytest.fixture
def stack() -> Iterator[ExitStack]:
    with ExitStack() as s:
        yield s


def _values(reader: ZenohReader, taken: list[float]) -> list[float]:
    taken.extend(s.A_value for s in reader.take(1000))
    return taken


def test_samples_cached_before_the_route_appeared_reach_the_station_in_order(
        stack: ExitStack) -> None:
    robot_side = _router(stack)
    station_side = _router(stack)
    robot = _bus(stack, robot_side, "robot-1")
    station = _bus(stack, station_side, "station")
    reader = station.reader("C_Monitored_Characteristic")
    writer = robot.writer("C_Monitored_Characteristic")
    for k in range(CACHED):
        writer.write(_value(k))
    # the robot goes on publishing while the route appears, as a running robot does: its
    # first sample to cross the new route is a live one
    written = CACHED
    _router(stack, (robot_side, station_side))
    taken: list[float] = []
    deadline = time.monotonic() + LINK_WAIT
    while not _values(reader, taken) and time.monotonic() < deadline:
        writer.write(_value(written))
        written += 1
        time.sleep(PERIOD)
    assert taken, f"no sample reached the station within {LINK_WAIT:g} s of the link"
    for _ in range(LIVE):
        writer.write(_value(written))
        written += 1
    wait_until(lambda: len(_values(reader, taken)) >= written,
               f"the station to read all {written} samples", 30.0,
               state=lambda: f"read {len(taken)}, the first {taken[:5]}")
    assert taken == [float(k) for k in range(written)]
    assert reader.malformed == 0
