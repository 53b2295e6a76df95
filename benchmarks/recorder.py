"""Recorder benchmark: sustained write rate, pipeline-side cost, bytes per operating hour.

1. ``Store.append`` of typical sample rows in batches (the writer thread's work), with
   ``durability`` full (fsync per commit) and normal; sustained rows/s over ``--rows``.
2. ``Recorder`` end to end: observations handed to ``on_observations`` (every one a state
   change, so every one is written) as fast as the pipeline thread can, until all are
   committed; the pipeline-side cost per observation and the sustained records/s through
   policy, queue, writer thread and SQLite commit. Two payloads: the minimal one (one
   value, no states, no message) and one like the hz observer's (four values, a state, a
   message). Also the pipeline-side cost of an observation the policy does not log
   (a healthy characteristic between samples: almost every observation on a real robot).
3. ``RingBuffer.offer`` cost per raw message.
4. Bytes per operating hour at the default policy for the thesis robot (3 nodes, 10
   observers at 1 Hz) and a 100-topic robot (250 observers at 1 Hz), measured by recording
   a simulated hour through the real policy and store (``blackbox log capacity``).

    .venv/bin/python benchmarks/recorder.py [--rows 500000] [--observations 500000]

``--compare REF`` instead measures (2) before and after side by side in one invocation:
the recorder of git revision ``REF`` (its ``src`` from ``git archive``) and of this tree,
each in a fresh subprocess, alternating, ``--repeats`` times; ``--busy-core`` keeps
another core busy (``while True: pass``) for the whole comparison. Prints the load
average, records/s min/median/max, CPU per record and the ratio to the 150k target.

    .venv/bin/python benchmarks/recorder.py --compare main --busy-core \
        --observations 200000 --repeats 5

``--breakdown`` (this tree only) splits the CPU per record of (2) by thread and step:
pipeline thread, writer thread, and in the writer the frame encoding (MessagePack), LZ4
and the SQLite insert of the frames.

    .venv/bin/python benchmarks/recorder.py --breakdown --busy-core --observations 200000
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sqlite3
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path
from typing import Any

from blackbox.events import MessageArrival
from blackbox.model import Code, Observation, Resource, State
from blackbox.record import Recorder, SnapshotConfig
from blackbox.record.retention import estimate_capacity, hundred_topic_robot, thesis_robot
from blackbox.record.settings import RecorderSettings
from blackbox.record.snapshot import RingBuffer
from blackbox.record.store import Row, Store


def store_rate(tmp: Path, rows: int, batch: int, durability: str) -> float:
    channels = [(f"/robot/topic_{k:03d}", "hz", f'{{"topic":"/robot/topic_{k:03d}"}}')
                for k in range(100)]
    store = Store.open(tmp / f"store-{batch}-{durability}.db", durability=durability)
    payload = {"values": {"period": 0.066712, "period_deviation": 0.001234}, "states": [1]}
    t0 = time.perf_counter()
    for start in range(0, rows, batch):
        store.append([Row(1.7e9 + i * 0.001, "sample", channels[i % 100], 0, payload)
                      for i in range(start, min(rows, start + batch))])
    elapsed = time.perf_counter() - t0
    store.close()
    return rows / elapsed


def _observations(count: int, realistic: bool) -> list[list[Observation]]:
    """Batches of 100 characteristics, each observation a change of code (and state)."""
    resources = [Resource(topic=f"/robot/topic_{k:03d}") for k in range(100)]
    ok, slow = (State(1, "ok"),), (State(2, "too_slow"),)
    batches = []
    for b in range(count // 100):
        faulty = b % 2 == 0
        code = Code.NO_STATE_FITS if faulty else Code.GENERAL_OK
        if realistic:
            batches.append([Observation(
                1.7e9 + b, "hz", r, code, slow if faulty else ok,
                {"period": 0.0667 + k * 1e-5, "period_deviation": 0.0012, "rate_hz": 14.99,
                 "silent_for": 0.011},
                f"period 0.0667 s (15 Hz) {'fits no state' if faulty else 'fits ok'}")
                for k, r in enumerate(resources)])
        else:
            batches.append([Observation(1.7e9 + b, "hz", r, code, values={"period": 0.0667})
                            for r in resources])
    return batches


def recorder_rate(tmp: Path, observations: int, realistic: bool = False) -> tuple[float, float]:
    """(pipeline-side µs per observation, records/s from first hand-over to last commit)."""
    per, rate, _ = recorder_run(tmp, observations, realistic)
    return per, rate


def recorder_run(tmp: Path, observations: int,
                 realistic: bool = False) -> tuple[float, float, float]:
    """:func:`recorder_rate` and the process's CPU µs per record (pipeline + writer)."""
    rec = Recorder(RecorderSettings(tmp / f"recorder-{realistic}.db", snapshot=None,
                                    queue_limit=observations * 2),
                   robot_id="bench")
    batches = _observations(observations, realistic)
    written_before = rec.written
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    for batch in batches:
        rec.on_observations(batch[0].time, batch)
    handed = time.perf_counter() - t0
    while rec.written - written_before < observations:
        time.sleep(0.002)
    total = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    rec.close()
    assert rec.dropped == 0, f"{rec.dropped} records dropped"
    return handed / observations * 1e6, observations / total, cpu / observations * 1e6


def pipeline_cost(tmp: Path, observations: int, realistic: bool) -> float:
    """Pipeline-side µs per logged observation with the writer thread idle (no GIL sharing)."""
    rec = Recorder(RecorderSettings(tmp / f"pipeline-{realistic}.db", snapshot=None,
                                    queue_limit=observations * 2, commit_interval=3600.0,
                                    commit_rows=observations * 2),
                   robot_id="bench")
    batches = _observations(observations, realistic)
    t0 = time.perf_counter()
    for batch in batches:
        rec.on_observations(batch[0].time, batch)
    per = (time.perf_counter() - t0) / observations * 1e6
    rec.close()
    return per


def unlogged_cost(tmp: Path, observations: int) -> float:
    """Pipeline-side µs per observation that the policy does not log (steady, healthy)."""
    rec = Recorder(RecorderSettings(tmp / "unlogged.db", snapshot=None), robot_id="bench")
    resources = [Resource(topic=f"/robot/topic_{k:03d}") for k in range(100)]
    ok = (State(1, "ok"),)
    batches = [[Observation(1.7e9 + b * 0.1, "hz", r, Code.GENERAL_OK, ok, {"period": 0.0667})
                for r in resources] for b in range(observations // 100)]
    rec.on_observations(batches[0][0].time, batches[0])  # the first is a change: logged
    t0 = time.perf_counter()
    for batch in batches[1:]:
        rec.on_observations(batch[0].time, batch)
    per = (time.perf_counter() - t0) / (observations - 100) * 1e6
    rec.close()
    return per


def ring_cost(messages: int) -> float:
    ring = RingBuffer(SnapshotConfig(before=10.0, max_bytes=64 * 1024 * 1024))
    data = b"m" * 2000
    arrivals = [MessageArrival(1.7e9 + i * 0.001, f"/t{i % 20}", "/p", 2000, raw=lambda: data)
                for i in range(messages)]
    t0 = time.perf_counter()
    for a in arrivals:
        ring.offer(a)
    return (time.perf_counter() - t0) / messages * 1e9


TARGET = 150_000.0
"""Records/s the recorder must sustain end to end with another core busy (issue 17)."""


def _worker(observations: int, realistic: bool) -> None:
    """One measurement in this process (whichever ``blackbox`` PYTHONPATH gives): JSON."""
    import blackbox.record.store as store_module

    with tempfile.TemporaryDirectory() as d:
        per, rate, cpu = recorder_run(Path(d), observations, realistic)
        size = sum(f.stat().st_size for f in Path(d).glob(f"recorder-{realistic}.db*"))
    print(json.dumps({"rate": rate, "pipeline_us": per, "cpu_us": cpu,
                      "bytes": size / observations,
                      "src": str(Path(store_module.__file__).parents[2])}))


def breakdown(observations: int, repeats: int, busy_core: bool) -> None:
    """Thread CPU per record of the pipeline, the writer and the writer's main steps."""
    import lz4.frame

    import blackbox.record.store as store_module
    from blackbox.record.writer import LogWriter

    spent: dict[str, float] = {}

    def timed(owner: Any, name: str, key: str) -> None:
        inner = getattr(owner, name)

        def wrapper(*args: Any, **kwargs: Any) -> Any:
            t = time.thread_time()
            try:
                return inner(*args, **kwargs)
            finally:
                spent[key] = spent.get(key, 0.0) + time.thread_time() - t
        setattr(owner, name, wrapper)

    timed(LogWriter, "_write_pending", "writer")
    timed(lz4.frame, "compress", "lz4")
    timed(store_module, "_pack", "encode+lz4")
    timed(store_module.Store, "_insert_frames", "sqlite frames")
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy_core else None
    try:
        if busy is not None:
            time.sleep(1.0)
        load = os.getloadavg()
        print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; another core busy: "
              f"{'yes' if busy else 'no'}; thread CPU us per record\n")
        print("| payload | process | pipeline thread | writer thread | MessagePack | LZ4 | "
              "SQLite insert of frames |")
        print("|---|---:|---:|---:|---:|---:|---:|")
        for _ in range(repeats):
            for realistic in (False, True):
                spent.clear()
                with tempfile.TemporaryDirectory() as d:
                    rec = Recorder(RecorderSettings(Path(d) / "b.db", snapshot=None,
                                                    queue_limit=observations * 2),
                                   robot_id="bench")
                    batches = _observations(observations, realistic)
                    before = rec.written
                    cpu, main = time.process_time(), time.thread_time()
                    for batch in batches:
                        rec.on_observations(batch[0].time, batch)
                    main = time.thread_time() - main
                    while rec.written - before < observations:
                        time.sleep(0.002)
                    cpu = time.process_time() - cpu
                    rec.close()
                per = {k: v / observations * 1e6 for k, v in spent.items()}
                print(f"| {'hz-like' if realistic else 'minimal'} | "
                      f"{cpu / observations * 1e6:.2f} | {main / observations * 1e6:.2f} | "
                      f"{per.get('writer', 0):.2f} | "
                      f"{per.get('encode+lz4', 0) - per.get('lz4', 0):.2f} | "
                      f"{per.get('lz4', 0):.2f} | {per.get('sqlite frames', 0):.2f} |")
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()


def _old_source(ref: str, into: Path) -> Path:
    """``src`` of git revision ``ref``, extracted into ``into``."""
    root = Path(__file__).resolve().parent.parent
    data = subprocess.run(["git", "-C", str(root), "archive", ref, "src"], check=True,
                          capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    return into / "src"


def _measure(src: Path, observations: int, realistic: bool) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, __file__, "--worker", "--observations",
                          str(observations), *(["--realistic"] if realistic else [])],
                         check=True, capture_output=True, text=True, env=env, timeout=600)
    result: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def compare(ref: str, observations: int, repeats: int, busy_core: bool) -> None:
    """Before (``ref``) and after (this tree), alternating, in one invocation."""
    new_src = Path(__file__).resolve().parent.parent / "src"
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy_core else None
    try:
        with tempfile.TemporaryDirectory() as d:
            old_src = _old_source(ref, Path(d))
            if busy is not None:
                time.sleep(1.0)  # let the busy loop take its core
            load_before = os.getloadavg()
            runs: dict[tuple[str, bool], list[dict[str, float]]] = {}
            for _ in range(repeats):
                for realistic in (False, True):
                    for label, src in ((ref, old_src), ("this tree", new_src)):
                        runs.setdefault((label, realistic), []).append(
                            _measure(src, observations, realistic))
            load_after = os.getloadavg()
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()
    cores = os.cpu_count()
    print(f"machine: {platform.machine()}, {cores} cores, Python {platform.python_version()}, "
          f"SQLite {sqlite3.sqlite_version}; another core busy: {'yes' if busy else 'no'}")
    print(f"load average (1/5/15 min) before: {load_before[0]:.2f} {load_before[1]:.2f} "
          f"{load_before[2]:.2f}, after: {load_after[0]:.2f} {load_after[1]:.2f} "
          f"{load_after[2]:.2f}")
    print(f"Recorder end to end (on_observations -> committed), {observations:,} "
          f"observations per run, {repeats} runs each, alternating\n")
    print("| payload | code | records/s min | median | max | median / 150k | "
          "CPU us/record | cores used | records/s per core of CPU | bytes/record |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for realistic in (False, True):
        medians = []
        for label in (ref, "this tree"):
            got = runs[(label, realistic)]
            rates = sorted(r["rate"] for r in got)
            med = statistics.median(rates)
            medians.append(med)
            cpu = statistics.median(r["cpu_us"] for r in got)
            used = statistics.median(r["cpu_us"] * r["rate"] / 1e6 for r in got)
            print(f"| {'hz-like' if realistic else 'minimal'} | {label} | {rates[0]:,.0f} | "
                  f"{med:,.0f} | {rates[-1]:,.0f} | {med / TARGET:.2f} | {cpu:.2f} | "
                  f"{used:.2f} | {1e6 / cpu:,.0f} | "
                  f"{statistics.median(r['bytes'] for r in got):.1f} |")
        print(f"| | after / before | | {medians[1] / medians[0]:.1f}x | | | | | | |")
    print("\nCPU us/record: the process's CPU time (pipeline and writer threads) over the "
          "records; cores used: that times records/s (the share of the machine the run "
          "got); records/s per core: 1 / CPU per record, what one free core would allow; "
          "bytes/record: the log's files after close over the records (the same values "
          "again and again: compresses far better than a robot's).")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=500_000)
    parser.add_argument("--observations", type=int, default=500_000)
    parser.add_argument("--compare", metavar="REF",
                        help="before (git REF) and after (this tree) side by side")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--busy-core", action="store_true",
                        help="keep another core busy while comparing")
    parser.add_argument("--breakdown", action="store_true",
                        help="CPU per record by thread and step (this tree)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--realistic", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        _worker(args.observations, args.realistic)
        return
    if args.compare:
        compare(args.compare, args.observations, args.repeats, args.busy_core)
        return
    if args.breakdown:
        breakdown(args.observations, args.repeats, args.busy_core)
        return
    print(f"machine: {platform.machine()}, {platform.processor() or 'cpu'}, "
          f"Python {platform.python_version()}, SQLite {sqlite3.sqlite_version}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        print("\n| writer | batch | durability | sustained records/s |")
        print("|---|---:|---|---:|")
        for batch, durability in ((1000, "full"), (10000, "full"), (1000, "normal")):
            rate = store_rate(tmp, args.rows, batch, durability)
            print(f"| Store.append | {batch} | {durability} | {rate:,.0f} |")
        costs = []
        for realistic in (False, True):
            per_obs, rate = recorder_rate(tmp, args.observations, realistic)
            costs.append(per_obs)
            what = "hz-like payload" if realistic else "minimal payload"
            print(f"| Recorder: on_observations -> committed, {what} | 1 s commits | full | "
                  f"{rate:,.0f} |")
        print(f"\npipeline-side cost per logged observation (policy + queue), while the "
              f"writer runs: {costs[0]:.2f} us minimal, {costs[1]:.2f} us hz-like")
        alone = [pipeline_cost(tmp, 200_000, realistic) for realistic in (False, True)]
        print(f"the same with the writer idle: {alone[0]:.2f} us minimal, "
              f"{alone[1]:.2f} us hz-like")
        print(f"pipeline-side cost per observation not logged: "
              f"{unlogged_cost(tmp, 200_000):.2f} us")
        print(f"ring buffer offer per raw message: {ring_cost(200_000):.0f} ns")
        print("\n| robot | observers | entries/h | bytes/h | 4000 h need | hours in 1 GB |")
        print("|---|---:|---:|---:|---:|---:|")
        for name, observers in (("thesis (3 nodes, 10 observers, 1 Hz)", thesis_robot()),
                                ("100 topics + 25 nodes (250 observers, 1 Hz)",
                                 hundred_topic_robot())):
            est = estimate_capacity(observers, 10**9, workdir=tmp)
            print(f"| {name} | {est.observers} | {est.entries_per_hour:,.0f} | "
                  f"{est.bytes_per_hour:,.0f} | {4000 * est.bytes_per_hour / 1e9:.3f} GB | "
                  f"{est.hours:,.0f} |")


if __name__ == "__main__":
    main()
