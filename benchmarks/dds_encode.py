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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--number", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    print(f"{'type':>28} {'XCDR':>4} {'cyclonedds us':>13} {'compiled us':>11} {'ratio':>6} "
          f"{'load':>5}")
    for sample in samples():
        for v2 in (False, True):
            encode = compile_encoder(type(sample), v2)
            assert encode(sample) == sample.serialize(use_version_2=v2)
            idl = min(timeit.repeat(lambda s=sample, v=v2: s.serialize(use_version_2=v),
                                    number=args.number, repeat=args.repeat))
            ours = min(timeit.repeat(lambda s=sample, e=encode: e(s), number=args.number,
                                     repeat=args.repeat))
            a, b = 1e6 * idl / args.number, 1e6 * ours / args.number
            print(f"{type(sample).__name__:>28} {2 if v2 else 1:>4} {a:13.1f} {b:11.2f} "
                  f"{a / b:6.0f} {os.getloadavg()[0]:5.2f}", flush=True)
    print(f"{'decode type':>28} {'XCDR':>4} {'cyclonedds us':>13} {'compiled us':>11} "
          f"{'ratio':>6} {'load':>5}")
    for sample in samples():
        for v2 in (False, True):
            payload = sample.serialize(use_version_2=v2)
            datatype: Any = type(sample)
            decode = compile_decoder(datatype, v2)
            assert decode(payload) == datatype.deserialize(payload) == sample
            idl = min(timeit.repeat(lambda p=payload, t=datatype: t.deserialize(p),
                                    number=args.number, repeat=args.repeat))
            ours = min(timeit.repeat(lambda p=payload, d=decode: d(p), number=args.number,
                                     repeat=args.repeat))
            a, b = 1e6 * idl / args.number, 1e6 * ours / args.number
            print(f"{type(sample).__name__:>28} {2 if v2 else 1:>4} {a:13.1f} {b:11.2f} "
                  f"{a / b:6.0f} {os.getloadavg()[0]:5.2f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
