"""``blackbox learn``: watch a healthy robot and write a configuration that observes it."""

from __future__ import annotations

import argparse
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TextIO

from blackbox.app import RunOptions, graceful_interrupts, open_robot
from blackbox.config.node import ConfigError
from blackbox.learn import Recording, learn_from, render_config, render_model, update_config
from blackbox.learn.update import write_files


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "learn", help="learn a configuration from a healthy run of a robot",
        description="Watch a healthy robot for a while and write a native configuration "
                    "that observes what was seen: rates, time-outs, message ages, numeric "
                    "fields, node liveness, CPU and memory, and the graph as the diagnosis "
                    "model. Rules and file layout: docs/learn.md.")
    p.add_argument("--source", default="sim:thesis",
                   help="sim:thesis, sim:TOPOLOGY.yaml, ros1 or ros1://HOST:PORT")
    p.add_argument("--duration", type=float, default=600.0, metavar="S",
                   help="seconds of source time to watch (default 600)")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="FILE",
                   help="configuration to write (default: robot.yaml, or the --update file)")
    p.add_argument("--update", type=Path, default=None, metavar="FILE",
                   help="refine this configuration: rewrite its learned blocks (merged with "
                        "the new run), keep everything else")
    p.add_argument("--robot-id", default=None, help="robot id for a new file (default robot)")
    p.add_argument("--simulated-clock", action="store_true",
                   help="run a simulated source as fast as possible instead of in real time")
    p.add_argument("--seed", type=int, default=1, help="seed of a simulated robot")
    p.add_argument("--discovery", type=float, default=10.0, metavar="S",
                   help="seconds to wait for the robot's graph before learning (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=learn_command)


def learn_command(args: argparse.Namespace) -> int:
    if not args.duration > 0:
        raise ConfigError(f"--duration must be > 0, got {args.duration:g}", "--duration")
    output: Path = args.output or args.update or Path("robot.yaml")
    old_text = None
    if args.update is not None:
        if not args.update.is_file():
            raise ConfigError("no such file to update", str(args.update))
        old_text = args.update.read_text(encoding="utf-8")
    options = RunOptions(source=args.source, simulated_clock=args.simulated_clock,
                         seed=args.seed, live=False)
    open_robot(options).close()  # a bad source spec fails here, before any waiting
    bar = None if args.quiet else ProgressBar(args.duration, sys.stderr)
    with graceful_interrupts() as stop:
        learned = learn_from(lambda: open_robot(options), args.duration,
                             progress=bar, discovery_timeout=args.discovery,
                             stop=stop.is_set)
    if bar is not None:
        bar.finish()
    when = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    model_path = output.with_name(output.stem + ".model.yaml")
    model_file = model_path.name
    if old_text is not None:
        text = update_config(old_text, str(args.update), learned, model_file, when)
    else:
        text = render_config(learned, args.robot_id or "robot", model_file, when)
    write_files(output, text, model_path, render_model(learned, when))
    observers = sum(len(b.entries) for b in learned.blocks)
    print(f"blackbox learn: {learned.duration:.0f} s of {learned.source}: "
          f"{len(learned.nodes)} nodes, {len(learned.topics)} topics -> {observers} "
          f"observers in {output} (diagnosis model {model_path})", file=sys.stderr)
    for note in learned.notes:
        print(f"  could not learn: {note}", file=sys.stderr)
    if not observers:
        print(f"blackbox learn: nothing was learned; {output} only says why", file=sys.stderr)
        return 1
    return 0


class ProgressBar:
    """One line on a terminal (redrawn), one line per 10 % otherwise."""

    def __init__(self, total: float, out: TextIO, width: int = 30) -> None:
        self.total = total
        self.out = out
        self.width = width
        self.tty = out.isatty()
        self.started = time.monotonic()
        self._shown = -1

    def __call__(self, done: float, rec: Recording) -> None:
        frac = min(1.0, done / self.total) if self.total > 0 else 1.0
        messages = sum(t.total for t in rec.topics.values())
        fill = int(frac * self.width)
        line = (f"learning [{'#' * fill}{'.' * (self.width - fill)}] {100 * frac:5.1f} % "
                f"{done:.0f}/{self.total:.0f} s, {len(rec.topics)} topics, {messages:,} "
                f"messages")
        if self.tty:
            self.out.write("\r" + line)
            self.out.flush()
        elif int(frac * 10) != self._shown:
            self._shown = int(frac * 10)
            self.out.write(line + "\n")
            self.out.flush()

    def finish(self) -> None:
        if self.tty:
            self.out.write("\n")
            self.out.flush()
