"""CPU cost of signed robot health: per sample on the robot and on the station.

    .venv/bin/python benchmarks/provenance_cpu.py [--rounds 400] [--repeat 3]

*Robot*: ``DdsHealthSink.on_observations`` for the thesis robot's five observations per
round (the samples the mapper makes, written to a real Cyclone participant on loopback),
once without a key and once with one (every sample then also gets a
``BlackBox_Sample_Signature``); the difference divided by the samples written is the cost
of signing one sample (digest of its CDR, Ed25519 signature, the signature's own write).
*Station*: :class:`~blackbox.station.trust.SampleGate` taking each signature and admitting
its sample (verify + re-encode + digest). Figures are process CPU time, median of
``--repeat``; nothing else should run meanwhile (the machine has two cores).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from blackbox.health.ids import robot_resource_id
from blackbox.station.trust import SampleGate
from blackbox.transport.auth import generate_key_pair
from blackbox.transport.participant import TOPIC_OF_TYPE
from blackbox.transport.provenance import SampleSigner
from blackbox.transport.publisher import DdsHealthSink

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from dds_blackbox_driver import faulty, healthy


def robot_seconds(rounds: int, key: Path | None, domain: int) -> tuple[float, int]:
    """CPU seconds of ``rounds`` publishing rounds and the samples written."""
    sink = DdsHealthSink("bench", domain_id=domain, signing_key_file=key)
    try:
        before = sink.written
        start = time.process_time()
        for i in range(rounds):
            t = time.time()
            sink.on_observations(t, faulty(t) if i % 2 else healthy(t))
        return time.process_time() - start, sink.written - before
    finally:
        sink.close()


def station_seconds(samples: int) -> float:
    key = Ed25519PrivateKey.generate()
    signer = SampleSigner(key, "bench")
    from blackbox.health.mapping import HealthMapper

    mapper = HealthMapper("bench")
    made: list[Any] = []
    while len(made) < samples:
        t = time.time()
        made += mapper.observations(t, healthy(t))
    pairs = [(TOPIC_OF_TYPE[type(s)], s, signer.sign(TOPIC_OF_TYPE[type(s)], s))
             for s in made[:samples]]
    gate = SampleGate(lambda: {robot_resource_id("bench"): ("bench", key.public_key())},
                      lambda *_: None)
    start = time.process_time()
    for topic, sample, signature in pairs:
        gate.signature(signature)
        if not gate.offer(topic, sample, 0.0):
            raise SystemExit(f"a signed {topic} was not admitted")
    return time.process_time() - start


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rounds", type=int, default=400)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--domain", type=int, default=230)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        key = Path(tmp) / "bench.key"
        generate_key_pair(key, "bench")
        plain, signed, verify = [], [], []
        written = 0
        for _ in range(args.repeat):
            cpu, written = robot_seconds(args.rounds, None, args.domain)
            plain.append(cpu / written)
            cpu, n = robot_seconds(args.rounds, key, args.domain)
            signed.append(cpu / n)
            verify.append(station_seconds(n) / n)
    per_plain, per_signed = statistics.median(plain), statistics.median(signed)
    print(f"robot: {written} samples per run ({args.rounds} rounds)")
    print(f"  publish without key: {per_plain * 1e6:7.1f} us CPU per sample")
    print(f"  publish with key:    {per_signed * 1e6:7.1f} us CPU per sample "
          f"(+{(per_signed - per_plain) * 1e6:.1f} us for the signature)")
    print(f"station: verify and admit {statistics.median(verify) * 1e6:7.1f} us CPU per sample")
    return 0


if __name__ == "__main__":
    sys.exit(main())
