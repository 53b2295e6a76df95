"""Cost of serialising and decoding one UCMS sample: cyclonedds's IDL machinery vs the
compiled encoder and decoder.

    .venv/bin/python benchmarks/dds_encode.py [--number 2000] [--repeat 7]

For the samples the black box writes in steady state (a characteristic value with one
threshold event reference, an entity with its references) both encoders run ``--number``
times per repeat; the best repeat is printed (the least disturbed by other processes on a
shared machine), with the load average. The bytes are checked equal first; then the same
for decoding those bytes (``deserialize`` against ``cdr_decoder``; the samples checked
equal first).
"""

from __future__ import annotations

import argparse
import os
import timeit
from collections.abc import Callable
from functools import partial
from typing import Any

from blackbox.health.types import (
    C_Monitored_Characteristic,
    C_Monitored_Entity,
    T_DateTimeType,
    T_HealthStatus,
    T_IdentifierType,
)
from blackbox.transport.cdr_decoder import compile_decoder
from blackbox.transport.cdr_encoder import compile_encoder


def samples() -> list[Any]:
    ids = [T_IdentifierType(3, i) for i in range(8)]
    return [
        C_Monitored_Characteristic(ids[0], T_DateTimeType(1_800_000_000, 123_456_789), 0.0667,
                                   ids[1], [ids[2]], ids[3]),
        C_Monitored_Entity(ids[1], T_DateTimeType(1_800_000_000, 5),
                           T_HealthStatus.L_HealthStatus_DEGRADED, False,
                           A_failureEvents_sourceID=ids[2:4], A_specification_sourceID=ids[4],
                           A_monitoredCharacteristics_sourceID=ids[:6]),
    ]


def side_by_side(label: str, cases: list[tuple[str, bool, Callable[[], object],
                                             Callable[[], object]]],
                 number: int, repeat: int) -> None:
    """One line per case: the best of ``repeat`` x ``number`` calls of cyclonedds's own
    code and of the compiled one, in microseconds per call, and the load average."""
    print(f"{label:>28} {'XCDR':>4} {'cyclonedds us':>13} {'compiled us':>11} {'ratio':>6} "
          f"{'load':>5}")
    for name, v2, theirs, ours in cases:
        a = 1e6 * min(timeit.repeat(theirs, number=number, repeat=repeat)) / number
        b = 1e6 * min(timeit.repeat(ours, number=number, repeat=repeat)) / number
        print(f"{name:>28} {2 if v2 else 1:>4} {a:13.1f} {b:11.2f} {a / b:6.0f} "
              f"{os.getloadavg()[0]:5.2f}", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--number", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    encoding = []
    decoding = []
    for sample in samples():
        for v2 in (False, True):
            datatype: Any = type(sample)
            encode = compile_encoder(datatype, v2)
            payload = sample.serialize(use_version_2=v2)
            assert encode(sample) == payload
            decode = compile_decoder(datatype, v2)
            assert decode(payload) == datatype.deserialize(payload) == sample
            name = datatype.__name__
            encoding.append((name, v2, partial(sample.serialize, use_version_2=v2),
                             partial(encode, sample)))
            decoding.append((name, v2, partial(datatype.deserialize, payload),
                             partial(decode, payload)))
    side_by_side("type", encoding, args.number, args.repeat)
    side_by_side("decode type", decoding, args.number, args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
