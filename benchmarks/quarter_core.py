"""A Raspberry-Pi-like budget: the thesis campaign on real ROS 1 with the black box limited to
a quarter of one core, against the same campaign unlimited.

    sudo .venv/bin/python benchmarks/quarter_core.py [--duration 300] [--seed 0]
        [--quota 0.25] [--out DIR] [--control]

Runs ``blackbox evaluate --source ros1 --runs 1`` twice, one after the other: unlimited, then
in a CPU cgroup with ``quota`` of one core (cgroup v2 ``cpu.max`` where the unified hierarchy
has the cpu controller, else cgroup v1 ``cpu.cfs_quota_us``). ``evaluate`` runs the black box
in its own process and starts the demo robot (roscore, the rospy nodes, the injected faults)
as child processes; those are moved back to the root cgroup as soon as they appear, so only
the black box is limited. Prints both runs' verdicts (every scored fault: detected, delay,
isolation; false alarms) and whether they are identical. Needs root.

``--control`` runs the unlimited campaign once more after the limited one. Two runs of a
real-time campaign are never identical in every detail (which observer flags a stall first
depends on where in its second it began, and the machine's load moves), so the fair test
of the limit is whether the limited run differs from the unlimited one more than the
unlimited one differs from itself: both counts are printed, fault by fault.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import psutil

from support import BLACKBOX, ROOT

V2 = Path("/sys/fs/cgroup")
V1 = Path("/sys/fs/cgroup/cpu")


def make_cgroup(name: str, quota: float) -> tuple[Path, Path]:
    """The limited group and the root group to move the robot's processes back to."""
    period = 100_000
    if "cpu" in (V2 / "cgroup.controllers").read_text(errors="replace").split() if \
            (V2 / "cgroup.controllers").exists() else False:
        group = V2 / name
        group.mkdir(exist_ok=True)
        (group / "cpu.max").write_text(f"{int(quota * period)} {period}\n")
        return group, V2
    group = V1 / name
    group.mkdir(exist_ok=True)
    (group / "cpu.cfs_period_us").write_text(f"{period}\n")
    (group / "cpu.cfs_quota_us").write_text(f"{int(quota * period)}\n")
    return group, V1


def _release_children(pid: int, group: Path, root: Path, stop: threading.Event) -> None:
    """Move every descendant of ``pid`` out of ``group`` (the robot is not limited)."""
    while not stop.wait(0.1):
        try:
            children = psutil.Process(pid).children(recursive=True)
        except psutil.Error:
            return
        inside = set((group / "cgroup.procs").read_text().split())
        for child in children:
            if str(child.pid) in inside:
                with contextlib.suppress(OSError):  # gone already
                    (root / "cgroup.procs").write_text(f"{child.pid}\n")


def campaign(out: Path, duration: float, seed: int, group: Path | None,
             root: Path | None) -> dict[str, Any]:
    cmd = [*BLACKBOX, "evaluate", "--source", "ros1", "--runs", "1", "--duration",
           str(duration), "--seed", str(seed), "--json", str(out)]
    if group is not None:  # enter the group before exec, so the black box starts limited
        cmd = ["sh", "-c", f'echo $$ > {group}/cgroup.procs && exec "$@"', "sh", *cmd]
    t0 = time.time()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    stop = threading.Event()
    if group is not None and root is not None:
        threading.Thread(target=_release_children, args=(proc.pid, group, root, stop),
                         daemon=True).start()
    p = psutil.Process(proc.pid)
    cpu = 0.0
    while proc.poll() is None:
        try:
            times = p.cpu_times()
            cpu = times.user + times.system
        except psutil.Error:
            pass
        time.sleep(0.5)
    stop.set()
    text = proc.stdout.read() if proc.stdout else ""
    if proc.returncode != 0:
        raise RuntimeError(f"evaluate failed ({proc.returncode}):\n{text[-3000:]}")
    result: dict[str, Any] = json.loads(out.read_text())
    result["_cpu_seconds"] = cpu
    result["_wall_seconds"] = time.time() - t0
    result["_output"] = text
    return result


def verdicts(result: dict[str, Any]) -> Any:
    """What must not change: per fault whether, by which observer and how it was detected
    and isolated, and the false alarms (delays move with the scheduling: printed apart)."""
    timing = ("start", "end", "delay", "isolation_delay", "time")
    out: list[Any] = []
    for run in result.get("runs", []):
        for f in run.get("faults", []):
            out.append({k: v for k, v in f.items() if not any(t in k for t in timing)})
        out.append({"false_positives": sorted(
            json.dumps([e["observer"], e["resource"]]) for e in run.get("false_positives", []))})
    return out


def delays(result: dict[str, Any]) -> list[Any]:
    return [(f.get("delay"), f.get("isolation_delay"))
            for run in result.get("runs", []) for f in run.get("faults", [])]


def differences(a: list[Any], b: list[Any]) -> list[str]:
    """What differs between two runs' :func:`verdicts`, one line per fault (or false-alarm
    set) that is not the same in both."""
    out = [f"fault {k}: {x} | {y}" for k, (x, y) in enumerate(zip(a, b, strict=False))
           if x != y]
    if len(a) != len(b):
        out.append(f"{len(a)} against {len(b)} entries")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quota", type=float, default=0.25)
    parser.add_argument("--out", type=Path, default=Path("/tmp/quarter-core"))
    parser.add_argument("--control", action="store_true",
                        help="run the unlimited campaign again after the limited one and "
                             "compare how much two unlimited runs differ")
    args = parser.parse_args(argv)
    if os.geteuid() != 0:
        print("quarter_core: needs root (a CPU cgroup)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    group, root = make_cgroup(f"blackbox-quarter-{os.getpid()}", args.quota)
    print(f"cgroup {group} ({'v1' if root == V1 else 'v2'}), quota {args.quota} core; "
          f"load at start {os.getloadavg()[0]:.2f}", flush=True)
    try:
        free = campaign(args.out / "unlimited.json", args.duration, args.seed, None, None)
        print(f"unlimited: black box CPU {free['_cpu_seconds']:.1f} s over "
              f"{free['_wall_seconds']:.0f} s; load {os.getloadavg()[0]:.2f}", flush=True)
        limited = campaign(args.out / "limited.json", args.duration, args.seed, group, root)
        stat = (group / "cpu.stat").read_text().replace("\n", "; ")
        print(f"limited:   black box CPU {limited['_cpu_seconds']:.1f} s over "
              f"{limited['_wall_seconds']:.0f} s; load {os.getloadavg()[0]:.2f}; "
              f"cgroup {stat}", flush=True)
        again = None
        if args.control:
            again = campaign(args.out / "unlimited-again.json", args.duration, args.seed,
                             None, None)
            print(f"unlimited again: black box CPU {again['_cpu_seconds']:.1f} s over "
                  f"{again['_wall_seconds']:.0f} s; load {os.getloadavg()[0]:.2f}",
                  flush=True)
    finally:
        group.rmdir()
    a, b = verdicts(free), verdicts(limited)
    runs = {"unlimited": free, "limited": limited}
    if again is not None:
        runs["unlimited-again"] = again
    for name, r in runs.items():
        (args.out / f"{name}.txt").write_text(r["_output"])
    print(json.dumps({name: verdicts(r) for name, r in runs.items()}, indent=1))
    for name, r in runs.items():
        print(f"detection / isolation delays, {name}: {delays(r)}")
    limit_diff = differences(a, b)
    print(f"unlimited vs limited: {len(limit_diff)} differences", *limit_diff, sep="\n  ")
    if again is None:
        print("verdicts identical" if a == b else "VERDICTS DIFFER")
        return 0 if a == b else 1
    control_diff = differences(a, verdicts(again))
    print(f"unlimited vs unlimited again (control): {len(control_diff)} differences",
          *control_diff, sep="\n  ")
    within = len(limit_diff) <= len(control_diff)
    print("the limit changes no more than a rerun does" if within else
          "THE LIMIT CHANGES MORE THAN A RERUN DOES")
    return 0 if within else 1


if __name__ == "__main__":
    raise SystemExit(main())
