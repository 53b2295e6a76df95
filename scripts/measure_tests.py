#!/usr/bin/env python3
"""Wall and CPU seconds of test files run one at a time, children included.

``--durations`` gives only wall seconds, and ``tests/cpu_time.py`` only counts the child
processes pytest itself reaps. A test's robots, routers, ``roscore`` and Chromium are often
grandchildren whose parent was killed, so they are reaped by init and their CPU is lost.
This script makes itself a child subreaper (Linux ``PR_SET_CHILD_SUBREAPER``): every
orphaned descendant of the pytest it starts is reparented to it, so its own
``RUSAGE_CHILDREN`` after reaping them all is the CPU of the whole process tree. While the
file runs it samples the tree with psutil every ``--every`` seconds to say which kinds of
process burned the CPU (pytest, robots under ``/usr/bin/python3``, ``blackbox``
subprocesses, Chromium, ...); processes shorter than a sample are left in ``unseen``.

    .venv/bin/python scripts/measure_tests.py tests/test_learn_real_imu.py tests/test_x.py
    nice -n 10 .venv/bin/python scripts/measure_tests.py --out cpu.tsv $(cat files.txt)

Each file prints one line (wall s, CPU s, CPU by kind); ``--per-test FILE`` appends the
per-test lines of ``tests/cpu_time.py`` (CPU of reaped children only, wall) to FILE.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import psutil

PR_SET_CHILD_SUBREAPER = 36
ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Measured:
    """One test file's run: wall, CPU of the whole tree, CPU by kind of process."""

    target: str
    exit_code: int
    wall: float
    cpu: float
    by_kind: dict[str, float] = field(default_factory=dict)

    def line(self) -> str:
        kinds = " ".join(f"{k}={v:.1f}" for k, v in sorted(self.by_kind.items(),
                                                           key=lambda kv: -kv[1]) if v >= 0.05)
        return (f"{self.wall:7.1f} {self.cpu:7.1f} rc={self.exit_code} {self.target}  "
                f"[{kinds}]")


def become_subreaper() -> None:
    """Orphaned descendants come to this process, so their CPU is counted when reaped."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_CHILD_SUBREAPER) failed")


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def kind_of(process: psutil.Process, pytest_pid: int) -> str:
    """What a process is, by its command line: the pytest process, a robot, Chromium..."""
    if process.pid == pytest_pid:
        return "pytest"
    try:
        cmd = process.cmdline()
    except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
        return "other"
    text = " ".join(cmd)
    exe = Path(cmd[0]).name if cmd else ""
    if "chrom" in text or "headless_shell" in text:
        return "chromium"
    if "playwright" in text or exe == "node":
        return "playwright"
    if "roscore" in text or "rosmaster" in text or exe == "rosout":
        return "roscore"
    if "blackbox" in text and ("ros2_robot" not in text and "ros1_robot" not in text):
        return "blackbox"
    if "ros2_robot" in text:
        return "ros2-robot"
    if "ros1_robot" in text or cmd[:1] == ["/usr/bin/python3"]:
        return "ros1-robot"
    if "postgres" in text:
        return "postgres"
    if exe.startswith("python"):
        return "python-other"
    return exe or "other"


def reap_all(deadline: float) -> list[int]:
    """Reap every descendant left (orphans come here); the pids still alive at ``deadline``."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return []
        if pid == 0:
            if time.monotonic() >= deadline:
                return [p.pid for p in psutil.Process().children()]
            time.sleep(0.1)


def measure(target: str, pytest_args: list[str], every: float, per_test: Path | None,
            python: str, log_dir: Path) -> Measured:
    """Run ``target`` alone under pytest (its output to a log in ``log_dir``)."""
    env = dict(os.environ)
    if per_test is not None:
        env["BLACKBOX_TEST_CPU"] = str(per_test)
    before = children_cpu()
    started = time.monotonic()
    log_dir.mkdir(parents=True, exist_ok=True)
    log = log_dir / (target.replace("/", "_").replace(":", "_")[:120] + ".log")
    with log.open("wb") as output:
        proc = subprocess.Popen([python, "-m", "pytest", "-q", "-p", "no:randomly",
                                 *pytest_args, target], cwd=ROOT, env=env, stdout=output,
                                stderr=subprocess.STDOUT)
    seen: dict[int, tuple[str, float]] = {}
    root = psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            tree = [root, *root.children(recursive=True)]
        except psutil.NoSuchProcess:
            tree = []
        orphans = [p for p in psutil.Process().children(recursive=True) if p.pid != proc.pid
                   and p not in tree]
        for p in [*tree, *orphans]:
            try:
                times = p.cpu_times()
                seen[p.pid] = (seen.get(p.pid, (kind_of(p, proc.pid), 0.0))[0],
                               times.user + times.system)
            except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
                continue
        time.sleep(every)
    wall = time.monotonic() - started
    left = reap_all(time.monotonic() + 30.0)
    if left:
        print(f"measure_tests: {target}: processes still alive 30 s after pytest: {left}",
              file=sys.stderr)
    cpu = children_cpu() - before
    by_kind: dict[str, float] = defaultdict(float)
    for kind, seconds in seen.values():
        by_kind[kind] += seconds
    by_kind["unseen"] = max(0.0, cpu - sum(by_kind.values()))
    return Measured(target, proc.returncode or 0, wall, cpu, dict(by_kind))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("targets", nargs="+", help="test files or node ids, run one at a time")
    parser.add_argument("--every", type=float, default=0.5, help="sampling period, seconds")
    parser.add_argument("--out", type=Path, help="also append each line to this file")
    parser.add_argument("--per-test", type=Path, help="BLACKBOX_TEST_CPU file (per test)")
    parser.add_argument("--logs", type=Path, default=Path("/tmp/measure_tests"),
                        help="directory for each run's pytest output")
    parser.add_argument("--python", default=str(ROOT / ".venv" / "bin" / "python"))
    parser.add_argument("--pytest-arg", action="append", default=[],
                        help="extra pytest argument (repeatable)")
    args = parser.parse_args()
    become_subreaper()
    print("   wall     cpu  target  [cpu by kind of process]", flush=True)
    for target in args.targets:
        measured = measure(target, args.pytest_arg, args.every, args.per_test, args.python,
                           args.logs)
        print(measured.line(), flush=True)
        if args.out is not None:
            with args.out.open("a", encoding="utf-8") as out:
                out.write(measured.line() + "\n")


if __name__ == "__main__":
    main()
