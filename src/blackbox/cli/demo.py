"""``blackbox demo``: the simulated thesis robot with random faults, watched live.

By default the black box and the station run as two processes that talk only over DDS
(loopback): the black box watches the simulated robot, records its health and publishes
UCMS health messages; ``blackbox listen`` shows what a remote station sees. ``--fast``
instead runs five simulated minutes in-process in a few seconds, printing state changes.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from blackbox.app import RunOptions, build, graceful_interrupts

DEMO_CONFIG = Path(__file__).resolve().parent.parent / "configs" / "thesis-extended.yaml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulated thesis robot with injected faults, watched live",
                       description="Run the black box on the simulated thesis robot while a "
                       "seeded random fault campaign breaks it, and a station listens over DDS.")
    p.add_argument("--duration", type=float, default=60.0, metavar="S",
                   help="seconds to run (default 60; 300 simulated seconds with --fast)")
    p.add_argument("--fast", action="store_true",
                   help="simulated clock, in one process: five robot minutes in a few seconds")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--domain", type=int, default=None,
                   help="DDS domain of the demo (default: derived from the process id)")
    p.add_argument("--out", type=Path, default=Path("out/demo"),
                   help="directory for the health log, JSON lines and ground truth")
    p.set_defaults(func=demo_command)


def demo_command(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    if args.fast:
        return fast_demo(args, out)
    return two_process_demo(args, out)


def run_arguments(args: argparse.Namespace, out: Path, duration: float) -> list[str]:
    return ["--config", str(DEMO_CONFIG), "--source", "sim:thesis", "--duration", str(duration),
            "--faults", "random", "--seed", str(args.seed),
            "--ground-truth", str(out / "ground_truth.jsonl"),
            "--observations", str(out / "observations.jsonl"),
            "--diagnoses", str(out / "diagnoses.jsonl"), "--events", str(out / "events.jsonl"),
            "--record", str(out / "blackbox.db")]


def fast_demo(args: argparse.Namespace, out: Path) -> int:
    duration = 300.0 if args.duration == 60.0 else args.duration
    options = RunOptions(
        config=DEMO_CONFIG, source="sim:thesis", duration=duration, simulated_clock=True,
        faults="random", seed=args.seed, ground_truth=out / "ground_truth.jsonl",
        observations=out / "observations.jsonl", diagnoses=out / "diagnoses.jsonl",
        events=out / "events.jsonl", record=out / "blackbox.db", live_interactive=False)
    with graceful_interrupts() as stop:
        stats = build(options).run(stop)
    print(f"demo: {stats.ended - stats.started:.1f} s of robot time, {stats.messages:,} messages,"
          f" {stats.faulty_observations:,} faulty observations, {stats.diagnoses} diagnoses; "
          f"records in {out}/", file=sys.stderr)
    return 0


def two_process_demo(args: argparse.Namespace, out: Path) -> int:
    domain = args.domain if args.domain is not None else 100 + os.getpid() % 100
    blackbox = [sys.executable, "-m", "blackbox"]
    log = (out / "blackbox.log").open("w")
    robot = subprocess.Popen(
        [*blackbox, "run", *run_arguments(args, out, args.duration), "--dds",
         "--domain", str(domain), "--quiet"], stdout=log, stderr=subprocess.STDOUT)
    print(f"demo: black box (pid {robot.pid}) watching the simulated thesis robot, publishing "
          f"on DDS domain {domain}; station below. Ctrl-C to stop.", file=sys.stderr)
    station = subprocess.Popen([*blackbox, "listen", "--domain", str(domain),
                                "--duration", str(args.duration + 2.0)])
    try:
        station.wait()
        robot.wait(timeout=10)
    except KeyboardInterrupt:
        for proc in (station, robot):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 10
        for proc in (station, robot):
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
    finally:
        for proc in (station, robot):
            if proc.poll() is None:
                proc.kill()
        log.close()
    print(f"demo: black box exited with {robot.returncode}; health log {out}/blackbox.db "
          f"(try: blackbox log query --db {out}/blackbox.db --kind failure), "
          f"black box output in {out}/blackbox.log", file=sys.stderr)
    return 0 if robot.returncode == 0 else 1
