"""The Zenoh bus on its own: settings that refuse bad endpoints in one line, key expressions
that a robot id cannot break, and a reader that survives payloads that are not samples.
A real in-process router on a free loopback port; no DDS involved."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from blackbox.cli import main
from blackbox.health.extension import C_Entity_Description
from blackbox.health.types import T_IdentifierType
from blackbox.transport.zenoh_bus import ZenohBus, ZenohSettings, key_part
from blackbox.transport.zenoh_router import RouterSettings, open_router
from conftest import wait_until
from zenoh_support import free_tcp_port


@pytest.mark.parametrize("endpoint", ["", "127.0.0.1:7447", "tcp/127.0.0.1", "http://x:1",
                                      "tcp/a b:1"])
def test_an_endpoint_that_is_not_one_is_refused_naming_it(endpoint: str) -> None:
    with pytest.raises(ValueError, match="not a Zenoh endpoint"):
        ZenohSettings((endpoint,))


def test_a_tls_certificate_without_its_key_is_refused() -> None:
    with pytest.raises(ValueError, match="needs its private key"):
        ZenohSettings(("tls/127.0.0.1:7447",), certificate="cert.pem").config()
    with pytest.raises(ValueError, match="needs --zenoh-certificate"):
        RouterSettings(("tls/127.0.0.1:7447",))


def test_the_router_command_refuses_a_bad_endpoint_with_one_line(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["router", "--listen", "tcp/127.0.0.1"]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [
        "error: not a Zenoh endpoint: 'tcp/127.0.0.1' (expected e.g. tcp/127.0.0.1:7447 or "
        "tls/host:7447)"]


@pytest.mark.parametrize(("robot_id", "chunk"), [("thesis-robot", "thesis-robot"),
                                                  ("a/b", "a_b"), ("*", "_"), ("**", "__"),
                                                  ("x$*y", "x__y"), ("", "_"),
                                                  ("robot 7#?", "robot_7__")])
def test_a_robot_id_is_one_chunk_of_the_key_whatever_it_contains(robot_id: str,
                                                                 chunk: str) -> None:
    assert key_part(robot_id) == chunk


@pytest.fixture
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    session: Any = open_router(RouterSettings((endpoint,)))
    yield endpoint
    session.close()


def description(robot: str) -> C_Entity_Description:
    return C_Entity_Description(A_sourceID=T_IdentifierType(1, 2), A_robotId=robot,
                                A_name="/usb_cam", A_kind="node",
                                A_parent_sourceID=T_IdentifierType(1, 1))


def test_payloads_that_are_not_samples_are_counted_and_the_next_sample_still_read(
        router: str) -> None:
    station = ZenohBus.open(ZenohSettings((router,)), "station")
    robot = ZenohBus.open(ZenohSettings((router,)), "thesis")
    raw_config = ZenohSettings((router,)).config()
    intruder: Any = zenoh.open(raw_config)
    try:
        reader = station.reader("BlackBox_Entity_Description")
        writer = robot.writer("BlackBox_Entity_Description")
        waiter = station.waiter([reader])
        key = "blackbox/intruder/BlackBox_Entity_Description"
        taken: list[Any] = []

        def garbage_then_a_sample_arrived() -> bool:
            intruder.put(key, b"\x00\x01 not CDR")
            intruder.put(key, b"")
            writer.write(description("thesis"))
            waiter.wait(0.2)
            taken.extend(reader.take(N=100))
            return bool(taken) and reader.malformed >= 2
        wait_until(garbage_then_a_sample_arrived,
                   "two malformed payloads counted and a real sample read")
        assert {(s.A_robotId, s.A_name) for s in taken} == {("thesis", "/usb_cam")}
    finally:
        intruder.close()
        robot.close()
        station.close()
