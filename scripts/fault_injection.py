"""What the ROS 1 and ROS 2 fault injectors (``scripts/ros*_robot/inject.py``) share: the
fault record, the random draws of a campaign, its options and its loop.

Pure standard library, because the ROS 1 injector runs under Debian's ``/usr/bin/python3``
and the ROS 2 one under the project's virtualenv; each adds this directory to its path.
"""

from __future__ import annotations

import argparse
import random
import signal
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

DEFAULT_RATES = {"/usb_cam/image_raw": 15.0, "/audio": 33.333, "/signal": 15.0}
"""The thesis robot's nominal publishing rates (Hz) by topic."""


@dataclass
class ActiveFault:
    kind: str
    component: str
    node: str
    start: float
    params: dict[str, float] = field(default_factory=dict)

    def record(self, end: float | None) -> dict[str, Any]:
        """The ground-truth line of this fault, in the simulator's format."""
        return {"start": self.start, "end": end, "kind": self.kind,
                "component": self.component, "node": self.node, "params": dict(self.params)}


class Injector(Protocol):
    def begin(self, kind: str, component: str, **params: float) -> ActiveFault: ...

    def end(self, fault: ActiveFault) -> dict[str, Any]: ...


def random_fault(rng: random.Random, kinds: list[str], nodes: Iterable[str],
                 topics: Iterable[str]) -> tuple[str, str, dict[str, float]]:
    """One fault drawn from ``kinds`` on the robot's ``nodes`` and ``topics``: (kind,
    component, parameters)."""
    kind = rng.choice(kinds)
    if kind == "kill":
        return kind, rng.choice(sorted(nodes)), {}
    if kind == "stall":
        return kind, rng.choice(sorted(topics)), {}
    if kind == "rate":
        topic = rng.choice(["/usb_cam/image_raw", "/signal"])
        factor = rng.choice([0.3, 0.5, 2.0])
        return kind, topic, {"hz": round(DEFAULT_RATES[topic] * factor, 3)}
    if kind == "offset":
        return kind, "/signal", {"value": rng.choice([-5.0, -3.0, 3.0, 5.0])}
    if kind == "scale":
        return kind, "/signal", {"factor": rng.choice([0.5, 1.5])}
    if kind == "stuck":
        return kind, "/signal", {}
    if kind == "drift":
        return kind, "/signal", {"rate": rng.choice([-1.0, 1.0])}
    if kind == "cpu_hog":
        return kind, rng.choice(sorted(nodes)), {"percent": 90.0}
    return kind, rng.choice(sorted(nodes)), {"rate": 10e6}


def span(text: str) -> tuple[float, float]:
    """``--length MIN:MAX`` (or ``N``): a range of seconds, 0 < MIN <= MAX."""
    lo, _, hi = text.partition(":")
    a, b = float(lo), float(hi or lo)
    if not 0 < a <= b:
        raise argparse.ArgumentTypeError(f"expected MIN:MAX seconds with 0 < MIN <= MAX: {text}")
    return a, b


def add_campaign_arguments(parser: argparse.ArgumentParser, default_kinds: Sequence[str]) -> None:
    """The options of a random campaign: ground truth file, length, seed, fault kinds
    (default ``default_kinds``), gaps, fault lengths, warm-up and the robot's log folder."""
    parser.add_argument("--truth", type=Path, required=True, help="ground truth JSON lines")
    parser.add_argument("--duration", type=float, default=300.0, help="seconds of faults")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--kinds", default=",".join(default_kinds))
    parser.add_argument("--mean-gap", type=float, default=20.0,
                        help="mean healthy seconds between faults")
    parser.add_argument("--length", type=span, default=(5.0, 15.0),
                        help="fault length range MIN:MAX seconds")
    parser.add_argument("--warmup", type=float, default=10.0,
                        help="healthy seconds before the first fault")
    parser.add_argument("--log-dir", type=Path)


def chosen_kinds(parser: argparse.ArgumentParser, args: argparse.Namespace,
                 known: Sequence[str]) -> list[str]:
    """The fault kinds of ``--kinds``; a usage error (exit 2) if any is not in ``known``."""
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = sorted(set(kinds) - set(known))
    if unknown or not kinds:
        parser.error(f"unknown kinds {unknown}; expected some of {', '.join(known)}")
    return kinds


def stop_on_signals() -> dict[str, bool]:
    """A flag, ``stop["now"]``, that SIGTERM and SIGINT set (the loops check it)."""
    stop = {"now": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(now=True))
    signal.signal(signal.SIGINT, lambda *_: stop.update(now=True))
    return stop


def sleep(stop: dict[str, bool], seconds: float) -> None:
    """Sleep ``seconds``, or less if ``stop["now"]`` is set meanwhile (by a signal)."""
    end = time.monotonic() + seconds
    while not stop["now"] and time.monotonic() < end:
        time.sleep(min(0.1, end - time.monotonic()))


def run_random(injector: Injector, rng: random.Random, kinds: list[str],
               robot: tuple[Iterable[str], Iterable[str]], args: argparse.Namespace,
               stop: dict[str, bool], rejoined: Callable[[str], object]) -> None:
    """One fault at a time for ``args.duration`` seconds after ``args.warmup`` healthy
    ones, on the robot's (nodes, topics) ``robot``: each lasts a draw from
    ``args.length``, then a healthy gap drawn with mean ``args.mean_gap``;
    ``rejoined(node)`` waits for a killed node to be back. A fault still active when this
    ends (stopped, or an error) is ended."""
    active: ActiveFault | None = None
    try:
        finish = time.monotonic() + args.duration
        sleep(stop, args.warmup)
        while not stop["now"] and time.monotonic() < finish:
            kind, component, params = random_fault(rng, kinds, *robot)
            active = injector.begin(kind, component, **params)
            print(f"{active.start:.3f} begin {kind} {component} {params}", flush=True)
            sleep(stop, rng.uniform(*args.length))
            rec = injector.end(active)
            active = None
            print(f"{rec['end']:.3f} end {kind} {component}", flush=True)
            if kind == "kill":
                rejoined(component)
            sleep(stop, rng.expovariate(1.0 / args.mean_gap))
    finally:
        if active is not None:
            injector.end(active)


def run_schedule(injector: Injector, schedule: list[dict[str, Any]], t0: float,
                 stop: dict[str, bool]) -> None:
    """Begin and end every fault of ``schedule`` at ``t0`` + its offsets (wall clock)."""
    steps: list[tuple[float, int, int]] = []
    for i, f in enumerate(schedule):
        steps.append((t0 + float(f["start"]), 1, i))
        if f.get("end") is not None:
            steps.append((t0 + float(f["end"]), 0, i))
    steps.sort()
    active: dict[int, ActiveFault] = {}
    try:
        for at, begin, i in steps:
            while not stop["now"] and time.time() < at:
                time.sleep(min(0.05, max(0.0, at - time.time())))
            if stop["now"]:
                return
            f = schedule[i]
            if begin:
                active[i] = injector.begin(f["kind"], f["component"], **f.get("params", {}))
                print(f"{active[i].start:.3f} begin {f['kind']} {f['component']}", flush=True)
            elif i in active:
                rec = injector.end(active.pop(i))
                print(f"{rec['end']:.3f} end {f['kind']} {f['component']}", flush=True)
    finally:
        for fault in active.values():
            injector.end(fault)
