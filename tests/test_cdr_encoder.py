"""The precompiled UCMS encoders write exactly the bytes cyclonedds's own serialisation
writes (every published type, XCDR1 and XCDR2, random samples with empty and long
sequences and non-ASCII strings), and an independent cyclonedds reader in another process
reads the samples the black box's writers send with them."""

from __future__ import annotations

import random
import subprocess
import sys
import time
from typing import Any

import pytest
from cyclonedds.idl import _machinery as m

from blackbox.health.extension import EXTENSION_TOPICS
from blackbox.health.types import (
    REMOTE_TOPICS,
    UCMS_TOPICS,
    C_Monitored_Characteristic,
    C_Monitored_Entity,
    T_DateTimeType,
    T_HealthStatus,
    T_IdentifierType,
)
from blackbox.transport.cdr_encoder import compile_encoder, encoder_for, sample_writer
from blackbox.transport.participant import Bus, TransportSettings
from isolation import fresh_domain
from station_support import dds_env

TYPES = {**UCMS_TOPICS, **EXTENSION_TOPICS, **REMOTE_TOPICS}
WITHOUT_ENCODER = {"BlackBox_Log_Request", "BlackBox_IBIT_Request", "BlackBox_Log_Reply",
                   "BlackBox_IBIT_Result", "BlackBox_Sample_Signature"}
"""Topics whose type holds a byte sequence (a machine the compiler leaves to cyclonedds):
the station's signed requests, and the robot's signatures (on log replies, IBIT results
and its health samples), which cyclonedds's own serialisation writes."""

_RANGES = {"b": 7, "h": 15, "i": 31, "q": 63, "B": 8, "H": 16, "I": 32, "Q": 64}


def _range_of(code: str) -> tuple[int, int]:
    bits = _RANGES[code]
    return (0, 2 ** bits - 1) if code.isupper() else (-(2 ** bits), 2 ** bits - 1)


def _random_value(machine: Any, rng: random.Random) -> Any:
    """A random value for what ``machine`` encodes, edge values included."""
    if isinstance(machine, m.InstanceMachine):
        idl = machine.type.__idl__
        machine = idl.v2_machine if machine.use_version_2 else idl.v1_machine
    if isinstance(machine, m.PrimitiveMachine):
        code = machine.code
        if code in "fd":
            return rng.choice([0.0, -1.5, 1e300, rng.uniform(-1e6, 1e6)]) if code == "d" \
                else rng.choice([0.0, 0.5, -2.25])
        if code == "?":
            return rng.random() < 0.5
        low, high = _range_of(code)
        return rng.choice([low, high, 0, rng.randint(low, high)])
    if isinstance(machine, m.EnumMachine):
        return rng.choice(list(machine.enum))
    if isinstance(machine, m.StringMachine):
        return rng.choice(["", "camera", "caméra ü 機器人", "x" * rng.randrange(1, 300)])
    if isinstance(machine, m.SequenceMachine):
        return [_random_value(machine.submachine, rng) for _ in range(rng.choice([0, 1, 3, 40]))]
    if isinstance(machine, m.PlainCdrV2SequenceOfPrimitiveMachine):  # bytes in XCDR2
        low, high = _range_of(machine.code)
        return [rng.randint(low, high) for _ in range(rng.choice([0, 1, 3, 64]))]
    if isinstance(machine, m.StructMachine):
        return machine.type(**{name: _random_value(sub, rng)
                               for name, sub in machine.members_machines.items()})
    raise AssertionError(f"no random value for {type(machine).__name__}")


@pytest.mark.parametrize("version_2", [False, True], ids=["xcdr1", "xcdr2"])
@pytest.mark.parametrize("name", sorted(set(TYPES) - WITHOUT_ENCODER))
def test_encoder_bytes_equal_cyclonedds_serialisation(name: str, version_2: bool) -> None:
    datatype = TYPES[name]
    encode = compile_encoder(datatype, version_2)
    idl = datatype.__idl__
    idl.populate()
    rng = random.Random(name)
    for _ in range(200):
        sample = _random_value(idl.v2_machine if version_2 else idl.v1_machine, rng)
        assert encode(sample) == sample.serialize(use_version_2=version_2), \
            f"{sample!r}\n{encode.__doc__}"


def test_only_types_with_byte_sequences_keep_cyclonedds_serialisation() -> None:
    without = {name for name, t in TYPES.items()
               if encoder_for(t, False) is None or encoder_for(t, True) is None}
    assert without == WITHOUT_ENCODER


def _hot_samples(count: int) -> list[Any]:
    out: list[Any] = []
    for i in range(count):
        out.append(C_Monitored_Characteristic(
            T_IdentifierType(7, 100 + i), T_DateTimeType(1_800_000_000 + i, 999_999_999),
            i * 0.125 - 3.0, T_IdentifierType(7, 2), [T_IdentifierType(7, j) for j in range(i % 3)],
            T_IdentifierType(7, 3)))
        out.append(C_Monitored_Entity(
            T_IdentifierType(7, 200 + i), T_DateTimeType(1_800_000_000 + i, i),
            list(T_HealthStatus)[i % 4], i % 2 == 0,
            A_failureEvents_sourceID=[T_IdentifierType(7, 9)] * (i % 4),
            A_monitoredCharacteristics_sourceID=[T_IdentifierType(7, 100 + i)]))
    return out


_READER = """
import sys, time
from cyclonedds.core import Qos, Policy
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic
from blackbox.health.types import C_Monitored_Characteristic, C_Monitored_Entity
from blackbox.transport.participant import LOOPBACK_CONFIG
from blackbox.transport.qos import qos_for
domain_id, want = int(sys.argv[1]), int(sys.argv[2])
domain = Domain(domain_id, LOOPBACK_CONFIG)
participant = DomainParticipant(domain_id)
sub = Subscriber(participant, Qos(Policy.Partition(["blackbox"])))
readers = [DataReader(sub, Topic(participant, t.__name__, t), qos_for(t.__name__))
           for t in (C_Monitored_Characteristic, C_Monitored_Entity)]
print("ready", flush=True)
seen = []
deadline = time.monotonic() + 30
while len(seen) < want and time.monotonic() < deadline:
    got = [s for r in readers for s in r.take(N=100)]
    seen.extend(got)
    if not got:
        time.sleep(0.02)
for s in seen:
    print(repr(s), flush=True)
"""


@pytest.mark.dds
def test_an_independent_cyclonedds_reader_reads_what_the_encoders_write() -> None:
    domain = fresh_domain()
    samples = _hot_samples(10)
    reader = subprocess.Popen([sys.executable, "-c", _READER, str(domain), str(len(samples))],
                              stdout=subprocess.PIPE, text=True, env=dds_env())
    bus = Bus.open(TransportSettings(domain_id=domain))
    try:
        assert reader.stdout is not None
        assert reader.stdout.readline().strip() == "ready"
        writers = {t: bus.writer(t.__name__) for t in (C_Monitored_Characteristic,
                                                      C_Monitored_Entity)}
        deadline = time.monotonic() + 20
        while not all(w.get_matched_subscriptions() for w in writers.values()):
            assert time.monotonic() < deadline, "waited 20 s for the reader to match"
            time.sleep(0.05)
        writes = {t: sample_writer(w) for t, w in writers.items()}
        assert all(f != w.write for f, w in zip(writes.values(), writers.values(), strict=True))
        for s in samples:
            writes[type(s)](s)
        out, _ = reader.communicate(timeout=40)
    finally:
        if reader.poll() is None:
            reader.kill()
        bus.close()
    got = out.splitlines()
    key = {repr(s): s for s in samples}
    assert sorted(got) == sorted(key)
