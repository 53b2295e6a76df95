"""CPU and peak memory of the black box on the thesis robot rebuilt as rclpy nodes (ROS 2
Kilted, Fast DDS), side by side with an rclpy ``hz`` script on the camera topic, and under a
load of many real rclpy publishers.

    .venv/bin/python benchmarks/ros2_overhead.py [--seconds 20] [--topics 100] [--rate 100]
                                                 [--processes 4] [--json out.json]

Phases, one after the other on this machine, each on its own ROS 2 domain (loopback):

1. the thesis robot (``scripts/ros2_robot``: /usb_cam 640x480 rgb8 at 15 Hz, /audio_capture
   ~33 Hz, /Signal_generator 15 Hz) with ``scripts/ros2_robot/hz.py /usb_cam/image_raw``
   alone (what ``ros2 topic hz`` does; there is no ``ros2`` CLI wheel);
2. the same robot with ``blackbox run`` and the ten observers of the thesis experiments
   11-20 (``observers_tests_11-20.yaml``) on ``--source ros2:DOMAIN``;
3. ``--processes`` rclpy processes publishing ``--topics`` Float64 topics at ``--rate`` Hz
   (reliable, keep last 10), first alone, then watched by ``blackbox run`` with one hz
   observer per topic: the publishers' achieved rate without and with the black box (its
   readers must not slow a reliable publisher) and the black box's received messages.

CPU is the process's user+system time over the measuring window divided by the window
(100 % = one core); peak RSS is the kernel's high-water mark (VmHWM) of the process.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import psutil

from support import (
    BLACKBOX,
    ROOT,
    THESIS_CONFIG,
    Usage,
    measure,
    peak_rss,
    print_usage,
    stop,
    summary_rate,
)

sys.path.insert(0, str(ROOT / "scripts" / "ros2_robot"))
from robot import NODE_SCRIPT, ThesisRobot2, ros2_env

HZ_SCRIPT = ROOT / "scripts" / "ros2_robot" / "hz.py"


def blackbox(config: Path, domain: int, log: Path) -> subprocess.Popen[bytes]:
    with log.open("wb") as out:
        return subprocess.Popen([*BLACKBOX, "run", "--config", str(config), "--source",
                                 f"ros2:{domain}", "--quiet"],
                                stdout=out, stderr=subprocess.STDOUT, cwd=ROOT,
                                env=ros2_env(domain))


def thesis_phases(seconds: float, warmup: float, work: Path, domain: int) -> list[Usage]:
    out: list[Usage] = []
    with ThesisRobot2(domain, log_dir=work / "thesis") as robot:
        robot.start()
        hz = subprocess.Popen([sys.executable, str(HZ_SCRIPT), "/usb_cam/image_raw"],
                              env=ros2_env(domain), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
        try:
            out.append(measure(hz, "rclpy hz.py /usb_cam/image_raw (raw, like ros2 topic hz)",
                               warmup, seconds))
        finally:
            stop(hz)
        log = work / "blackbox-thesis.log"
        bb = blackbox(THESIS_CONFIG, domain, log)
        try:
            usage = measure(bb, "blackbox run, 10 thesis observers (tests 11-20), "
                            "--source ros2", warmup, seconds)
        finally:
            stop(bb)
        rate = summary_rate(log)
        if rate is not None:
            usage.note = (f"received {rate:.1f} msg/s over the whole run incl. discovery "
                          f"(the robot publishes {15 + 33.3 + 15:.1f})")
        out.append(usage)
    return out


def published(reports: list[Path]) -> float:
    """Rounds per second summed over the publishers' report files (rounds x topics later)."""
    total = 0.0
    for r in reports:
        text = r.read_text().split() if r.exists() else []
        if len(text) == 2 and float(text[1]) > 0:
            total += int(text[0]) / float(text[1])
    return total


def rounds(reports: list[Path]) -> int:
    """Rounds published so far, summed over the publishers (files replaced atomically)."""
    total = 0
    for r in reports:
        with contextlib.suppress(OSError, ValueError, IndexError):
            total += int(r.read_text().split()[0])
    return total


def load_phase(seconds: float, warmup: float, work: Path, topics: int, rate: float,
               processes: int, domain: int) -> list[Usage]:
    per = topics // processes
    names = [f"load{i}" for i in range(processes)]
    reports = [work / f"{n}.count" for n in names]
    pubs = [subprocess.Popen([sys.executable, str(NODE_SCRIPT), "load", "--name", n,
                              "--topics", str(per), "--rate", str(rate), "--report", str(r)],
                             env=ros2_env(domain), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL) for n, r in zip(names, reports,
                                                                        strict=True)]
    config = work / "load.yaml"
    lines = ["version: 1", "robot: {id: load}", "observers:"]
    for n in names:
        for i in range(per):
            lines.append(f"  - {{type: hz, topic: /{n}/t{i}, filter: {{type: mean, "
                         f"window_size: 50, deviation: std_deviation}}, states: [{{number: 1, "
                         f"name: ok, period: {{value: {{type: gauss, mean: {1 / rate}, "
                         f"std_deviation: {0.5 / rate}}}}}}}]}}")
    config.write_text("\n".join(lines) + "\n")
    out: list[Usage] = []
    try:
        time.sleep(warmup)
        r0, t0 = rounds(reports), time.monotonic()
        time.sleep(seconds)
        alone = (rounds(reports) - r0) * per / (time.monotonic() - t0)
        log = work / "blackbox-load.log"
        bb = blackbox(config, domain, log)
        try:
            p = psutil.Process(bb.pid)
            time.sleep(warmup)
            c0, r0, t0 = sum(p.cpu_times()[:2]), rounds(reports), time.monotonic()
            time.sleep(seconds)
            c1, r1, t1 = sum(p.cpu_times()[:2]), rounds(reports), time.monotonic()
            usage = Usage(f"blackbox run, {per * processes} hz observers",
                          100.0 * (c1 - c0) / (t1 - t0), peak_rss(bb.pid) / 1e6, t1 - t0)
            watched = (r1 - r0) * per / (t1 - t0)
            pub_cpu = 0.0
            procs = [psutil.Process(x.pid) for x in pubs]
            for proc in procs:
                proc.cpu_percent(None)
            time.sleep(2.0)
            pub_cpu = sum(proc.cpu_percent(None) for proc in procs)
        finally:
            stop(bb)
        received = summary_rate(log)
        got, sent = keep_up(domain, [f"/{n}/t{i}" for n in names for i in range(per)],
                            reports, per, warmup, seconds)
        usage.note = (f"{per * processes} topics x {rate:g} Hz from {processes} rclpy "
                      f"processes: published {alone:.0f} msg/s alone, {watched:.0f} msg/s "
                      f"while watched; black box received "
                      f"{received or 0:.0f} msg/s over its whole run incl. discovery; "
                      f"publishers used {pub_cpu:.0f} % CPU; the source alone (in-process) "
                      f"counted {got:,} of {sent:,} messages published in a {seconds:g} s window")
        out.append(usage)
    finally:
        for x in pubs:
            stop(x)
    return out


def keep_up(domain: int, topics: list[str], reports: list[Path], per: int, warmup: float,
            seconds: float) -> tuple[int, int]:
    """Messages the ROS 2 source received vs published in the same window (publishers'
    report files are written ten times a second; the window is aligned on their updates)."""
    from blackbox.events import Interest, MessageArrival
    from blackbox.sources.ros2 import Ros2Source

    source = Ros2Source(domain)
    source.start(Interest(frozenset(topics)))
    try:
        source.poll(time.time() + warmup)
        start_rounds = _wait_report(reports)
        source.poll(time.time())
        got = 0
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            got += sum(isinstance(e, MessageArrival) for e in source.poll(time.time() + 0.1))
        end_rounds = _wait_report(reports)
        got += sum(isinstance(e, MessageArrival) for e in source.poll(time.time()))
        sent = (end_rounds - start_rounds) * per
    finally:
        source.close()
    return got, sent


def _wait_report(reports: list[Path]) -> int:
    """The publishers' round count right after they next update it."""
    before = {r: r.stat().st_mtime_ns for r in reports}
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline and any(r.stat().st_mtime_ns == before[r]
                                              for r in reports):
        time.sleep(0.005)
    return rounds(reports)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="measuring window")
    parser.add_argument("--warmup", type=float, default=5.0)
    parser.add_argument("--topics", type=int, default=100)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--processes", type=int, default=4)
    parser.add_argument("--skip-load", action="store_true")
    parser.add_argument("--skip-thesis", action="store_true")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    domain = random.Random(os.getpid()).randrange(200, 230)
    rows: list[Usage] = []
    with tempfile.TemporaryDirectory(prefix="ros2-bench-") as tmp:
        work = Path(tmp)
        if not args.skip_thesis:
            rows += thesis_phases(args.seconds, args.warmup, work, domain)
        if not args.skip_load:
            rows += load_phase(args.seconds, args.warmup, work, args.topics, args.rate,
                               args.processes, domain + 1)
    print_usage(rows)
    if len(rows) >= 2 and not args.skip_thesis and rows[0].cpu_percent > 0:
        print(f"ratio black box / hz CPU: {rows[1].cpu_percent / rows[0].cpu_percent:.2f}")
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
