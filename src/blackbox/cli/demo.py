"""``blackbox demo``: the simulated thesis robot with random faults, watched live."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from blackbox.app import RunOptions, build, graceful_interrupts

DEMO_CONFIG = Path(__file__).resolve().parent.parent / "configs" / "thesis-extended.yaml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulated thesis robot with injected faults, watched live",
                       description="Run the black box on the simulated thesis robot while a "
                       "seeded random fault campaign breaks it.")
    p.add_argument("--duration", type=float, default=60.0, metavar="S",
                   help="seconds to run (default 60)")
    p.add_argument("--fast", action="store_true",
                   help="simulated clock: five minutes of robot time in a few seconds")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--out", type=Path, default=Path("out/demo"),
                   help="directory for observations, diagnoses and ground truth")
    p.set_defaults(func=demo_command)


def demo_command(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    duration = 300.0 if args.fast and args.duration == 60.0 else args.duration
    options = RunOptions(
        config=DEMO_CONFIG, source="sim:thesis", duration=duration,
        simulated_clock=args.fast, faults="random", seed=args.seed,
        ground_truth=out / "ground_truth.jsonl", observations=out / "observations.jsonl",
        diagnoses=out / "diagnoses.jsonl", events=out / "events.jsonl",
        record=out / "blackbox.db",
        live_interactive=None if not args.fast else False,
    )
    blackbox = build(options)
    with graceful_interrupts() as stop:
        stats = blackbox.run(stop)
    print(f"demo: {stats.ended - stats.started:.1f} s of robot time, {stats.messages:,} messages,"
          f" {stats.faulty_observations:,} faulty observations, {stats.diagnoses} diagnoses; "
          f"records in {out}/", file=sys.stderr)
    return 0
