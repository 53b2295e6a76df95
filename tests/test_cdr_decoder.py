"""The precompiled UCMS decoders read exactly what cyclonedds's own ``deserialize`` reads:
the same sample for random samples of every type they compile (XCDR1 and XCDR2, empty and
long sequences, non-ASCII strings), and for truncated, bit-flipped and foreign payloads
either the same sample or, where cyclonedds raises, an error (which the Zenoh reader
counts as malformed, as before)."""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any

import pytest
import zenoh

from blackbox.health.extension import EXTENSION_TOPICS
from blackbox.health.types import (
    REMOTE_TOPICS,
    UCMS_TOPICS,
    C_Monitored_Characteristic,
    T_DateTimeType,
    T_IdentifierType,
)
from blackbox.transport.cdr_decoder import compile_decoder, decoder_for
from blackbox.transport.cdr_layout import UnsupportedMachine
from blackbox.transport.zenoh_bus import ZenohBus, ZenohSettings
from blackbox.transport.zenoh_router import RouterSettings, open_router
from conftest import wait_until
from test_cdr_encoder import _random_value
from zenoh_support import free_tcp_port

TYPES = {**UCMS_TOPICS, **EXTENSION_TOPICS, **REMOTE_TOPICS}


def _compiles(datatype: type) -> bool:
    try:
        compile_decoder(datatype, False)
        compile_decoder(datatype, True)
    except UnsupportedMachine:
        return False
    return True


COMPILED = sorted(name for name, t in TYPES.items() if _compiles(t))


def _outcome(decode: Callable[[bytes], Any], payload: bytes) -> str:
    """The sample's repr (types, enum members and all), or that decoding raised."""
    try:
        return repr(decode(payload))
    except Exception:
        return "raises"


def _random_samples(name: str, version_2: bool, count: int) -> list[Any]:
    datatype: Any = TYPES[name]
    datatype.__idl__.populate()
    machine = datatype.__idl__.v2_machine if version_2 else datatype.__idl__.v1_machine
    rng = random.Random(f"{name}-{version_2}")
    return [_random_value(machine, rng) for _ in range(count)]


def test_every_type_the_buses_carry_has_a_compiled_decoder() -> None:
    assert set(COMPILED) == set(TYPES)
    assert decoder_for(C_Monitored_Characteristic) is not C_Monitored_Characteristic.deserialize


@pytest.mark.parametrize("version_2", [False, True], ids=["xcdr1", "xcdr2"])
@pytest.mark.parametrize("name", COMPILED)
def test_a_compiled_decoder_reads_the_sample_cyclonedds_reads(name: str,
                                                              version_2: bool) -> None:
    datatype: Any = TYPES[name]
    compiled = compile_decoder(datatype, version_2)
    for sample in _random_samples(name, version_2, 200):
        payload = sample.serialize(use_version_2=version_2)
        assert repr(compiled(payload)) == repr(datatype.deserialize(payload)) == repr(sample), \
            compiled.__doc__


@pytest.mark.parametrize("version_2", [False, True], ids=["xcdr1", "xcdr2"])
@pytest.mark.parametrize("name", COMPILED)
def test_a_damaged_payload_gives_what_cyclonedds_gives(name: str, version_2: bool) -> None:
    """Every prefix of some samples, random bit flips and random bytes after a valid
    header: where the compiled decoder returns a sample it is cyclonedds's, and the
    decoder the reader uses answers exactly as cyclonedds does (sample or error)."""
    datatype: Any = TYPES[name]
    compiled = compile_decoder(datatype, version_2)
    decode = decoder_for(datatype)
    rng = random.Random(f"damage-{name}-{version_2}")
    payloads: list[bytes] = []
    for sample in _random_samples(name, version_2, 30):
        whole = sample.serialize(use_version_2=version_2)
        payloads.extend(whole[:cut] for cut in range(4, len(whole), max(1, len(whole) // 40)))
        for _ in range(10):
            damaged = bytearray(whole)
            for _ in range(rng.choice([1, 2, 8])):
                at = rng.randrange(4, len(damaged)) if len(damaged) > 4 else 0
                damaged[at] ^= 1 << rng.randrange(8)
            payloads.append(bytes(damaged))
        payloads.append(whole[:4] + bytes(rng.randrange(256) for _ in range(rng.randrange(60))))
    assert len(payloads) > 500
    decoded = 0
    for payload in payloads:
        expected = _outcome(datatype.deserialize, payload)
        assert _outcome(decode, payload) == expected, payload.hex()
        got = _outcome(compiled, payload)
        if got != "raises":
            decoded += 1
            assert got == expected, f"{payload.hex()}\n{compiled.__doc__}"
    assert decoded > 0, "no damaged payload decoded: the comparison compared nothing"


@pytest.mark.parametrize("header", [b"\x00\x00\x00\x00", b"\x00\x06\x00\x00",
                                    b"\x00\x81\x00\x00", b"\x00\x0b\x00\x00"],
                         ids=["xcdr1-big-endian", "xcdr2-big-endian", "signed-flags", "pl-cdr2"])
def test_other_encapsulations_are_read_as_cyclonedds_reads_them(header: bytes) -> None:
    sample = C_Monitored_Characteristic(
        T_IdentifierType(3, 4), T_DateTimeType(1_800_000_000, 5), 2.5, T_IdentifierType(3, 1),
        [T_IdentifierType(3, 9)], T_IdentifierType(3, 2))
    decode = decoder_for(C_Monitored_Characteristic)
    for version_2 in (False, True):
        body = sample.serialize(use_version_2=version_2)[4:]
        payload = header + body
        assert _outcome(decode, payload) == _outcome(C_Monitored_Characteristic.deserialize,
                                                     payload)


def test_the_zenoh_reader_takes_compiled_samples_and_counts_what_is_not_one() -> None:
    """Through a real router: characteristic values come out as the samples written, and
    a truncated value and a foreign payload are counted as malformed, not raised."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    router: Any = open_router(RouterSettings((endpoint,)))
    station = ZenohBus.open(ZenohSettings((endpoint,)), origin="station")
    robot = ZenohBus.open(ZenohSettings((endpoint,)), origin="robot-1")
    intruder: Any = zenoh.open(ZenohSettings((endpoint,)).config())
    try:
        reader = station.reader("C_Monitored_Characteristic")
        writer = robot.writer("C_Monitored_Characteristic")
        waiter = station.waiter([reader])
        samples = [C_Monitored_Characteristic(
            T_IdentifierType(1, 1000 + i), T_DateTimeType(1_800_000_000 + i, i), i * 0.5,
            T_IdentifierType(1, 1), [T_IdentifierType(1, 7)] * (i % 3), T_IdentifierType(1, 2))
            for i in range(50)]
        probe = C_Monitored_Characteristic(T_IdentifierType(1, 1))
        taken: list[Any] = []

        def probe_arrived() -> bool:
            writer.write(probe)
            waiter.wait(0.2)
            taken.extend(reader.take(N=100))
            return bool(taken)

        wait_until(probe_arrived, "the station's reader to hear the robot's writer")
        garbage = [samples[1].serialize()[:20], b"\x00\x01\x00\x00not a sample"]
        unreadable = [_outcome(C_Monitored_Characteristic.deserialize, g) for g in garbage]
        assert unreadable == ["raises", "raises"]
        key = robot.key("robot-1", "C_Monitored_Characteristic")
        for sample in samples:
            writer.write(sample)
        for payload in garbage:
            intruder.put(key, payload)
        values: list[Any] = []

        def everything_arrived() -> bool:
            waiter.wait(0.2)
            values.extend(s for s in reader.take(N=100) if s.A_sourceID.A_instanceId >= 1000)
            return len(values) >= len(samples) and reader.malformed >= len(garbage)

        wait_until(everything_arrived, "50 samples taken and the damaged payloads counted")
        assert [repr(s) for s in values] == [repr(s) for s in samples]
        assert reader.malformed == len(garbage)
    finally:
        intruder.close()
        robot.close()
        station.close()
        router.close()
