"""DDS health stream benchmark: bytes per second and fault-to-station latency.

Part 1 publishes the thesis robot's health stream (3 nodes, 10 observers at 1 Hz) through
``DdsHealthSink`` for ``--seconds`` and reports the CDR payload bytes written per second
(exact, from serializing every written sample). RTPS framing, heartbeats and acks come
on top; the loopback byte counter cannot separate them from other traffic on a shared
machine, so it is not reported.

Part 2 measures the latency from fault detection (the moment the sink receives the failing
observation) to a listener in another process taking the Threshold Exceedence Event:
``--faults`` fault onsets, each followed by a recovery. Both processes read the same clock.

    .venv/bin/python benchmarks/dds_health.py --seconds 30 --faults 300
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

from blackbox.model import Code, Observation, Resource, State

NODES = ("/usb_cam", "/audio_capture", "/signal_generator")


def thesis_observations(t: float, faulty_camera: bool = False) -> list[Observation]:
    ok = (State(1, "ok"),)
    cam = Resource(topic="/usb_cam/image_raw", publishers=("/usb_cam",))
    audio = Resource(topic="/audio", publishers=("/audio_capture",))
    signal = Resource(topic="/signal", publishers=("/signal_generator",))
    camera = (Observation(t, "hz", cam, Code.NO_STATE_FITS, (), {"period": 0.5})
              if faulty_camera else Observation(t, "hz", cam, Code.GENERAL_OK, ok,
                                                {"period": 0.0667}))
    return [
        camera,
        Observation(t, "timeout", cam, Code.GENERAL_OK),
        Observation(t, "hz", audio, Code.GENERAL_OK, ok, {"period": 0.0333}),
        Observation(t, "timeout", audio, Code.GENERAL_OK),
        Observation(t, "hz", signal, Code.GENERAL_OK, ok, {"period": 0.0667}),
        Observation(t, "scores", signal, Code.GENERAL_OK, ok, {"score": 15.0}),
        *(Observation(t, "activated", Resource(node=n), Code.GENERAL_OK) for n in NODES),
        Observation(t, "resources", Resource(node="/usb_cam"), Code.GENERAL_OK, ok,
                    {"cpu": 3.0, "memory": 2.1e7}),
    ]


def listener(domain: int, expected: int) -> int:
    """Child process: print one latency (ms) per Threshold Exceedence Event."""
    from blackbox.health.types import seconds_of
    from blackbox.transport.participant import Bus, TransportSettings

    bus = Bus.open(TransportSettings(domain))
    reader = bus.reader("C_Threshold_Exceedence_Event")
    print("ready", flush=True)
    got = 0
    deadline = time.monotonic() + 120
    while got < expected and time.monotonic() < deadline:
        for s in reader.take_iter(timeout=100_000_000):
            now = time.time()
            print(f"{(now - seconds_of(s.A_eventOccurrenceDate)) * 1000:.3f}", flush=True)
            got += 1
    bus.close()
    return 0


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--faults", type=int, default=300)
    p.add_argument("--domain", type=int, default=150 + os.getpid() % 50)
    p.add_argument("--listener", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.listener:
        return listener(args.domain, args.faults)
    os.environ.pop("CYCLONEDDS_URI", None)

    from blackbox.transport.publisher import DdsHealthSink

    child = subprocess.Popen([sys.executable, __file__, "--listener", "--domain",
                              str(args.domain), "--faults", str(args.faults)],
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None and child.stdout.readline().strip() == "ready"
    sink = DdsHealthSink("thesis", domain_id=args.domain)
    writer = sink._writers[next(iter(sink._writers))]
    deadline = time.monotonic() + 10
    while not writer.get_matched_subscriptions() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)

    # Part 1: the steady 1 Hz stream.
    payload = samples = 0
    original = sink._write

    def counting(batch_in):
        nonlocal payload, samples
        batch = list(batch_in)
        samples += len(batch)
        payload += sum(len(s.serialize()) for s in batch)
        original(batch)

    sink._write = counting  # type: ignore[method-assign]
    start = time.time()
    ticks = int(args.seconds)
    for i in range(ticks):
        t = time.time()
        sink.on_observations(t, thesis_observations(t))
        time.sleep(max(0.0, start + i + 1 - time.time()))
    elapsed = time.time() - start
    sink._write = original  # type: ignore[method-assign]

    # Part 2: fault onsets and recoveries, 20 ms apart.
    for _ in range(args.faults):
        t = time.time()
        sink.on_observations(t, thesis_observations(t, faulty_camera=True))
        time.sleep(0.02)
        for _ in range(3):  # clear_after = 3 good observations
            t = time.time()
            sink.on_observations(t, thesis_observations(t))
        time.sleep(0.02)
    latencies = []
    for line in child.stdout:
        latencies.append(float(line))
        if len(latencies) >= args.faults:
            break
    child.wait(timeout=30)
    sink.close()
    latencies.sort()
    q = statistics.quantiles(latencies, n=100) if len(latencies) >= 2 else [float("nan")] * 99
    result = {
        "steady_seconds": round(elapsed, 1),
        "observations_per_second": 10,
        "cdr_payload_bytes_per_second": round(payload / elapsed, 1),
        "samples_per_second": round(samples / elapsed, 1),
        "faults": args.faults,
        "events_received": len(latencies),
        "latency_ms_p50": round(q[49], 3),
        "latency_ms_p99": round(q[98], 3),
        "latency_ms_max": round(latencies[-1], 3) if latencies else None,
    }
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
