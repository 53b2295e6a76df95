"""CPU and peak memory of the black box on the real thesis robot (Debian ROS 1), side by side
with ``rostopic hz`` on the camera topic, and under a load of many real publishers.

    .venv/bin/python benchmarks/ros1_overhead.py [--seconds 30] [--topics 100] [--rate 100]
                                                 [--processes 4] [--json out.json]

Phases, one after the other on this machine:

1. the thesis robot (roscore, /usb_cam 640x480 rgb8 at 15 Hz, /audio_capture ~33 Hz,
   /Signal_generator 15 Hz) with ``rostopic hz /usb_cam/image_raw`` alone;
2. the same robot with ``blackbox run`` and the ten observers of the thesis experiments
   11-20 (``observers_tests_11-20.yaml``) on ``--source ros1://127.0.0.1:PORT``;
3. a bare master with ``--processes`` rospy processes publishing ``--topics`` Float64
   topics at ``--rate`` Hz, watched by ``blackbox run`` with one hz observer per topic.

CPU is the process's user+system time over the measuring window divided by the window
(100 % = one core); peak RSS is the kernel's high-water mark (VmHWM) of the process.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
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
    print_usage,
    stop,
    summary_rate,
)

sys.path.insert(0, str(ROOT / "scripts" / "ros1_robot"))
from robot import ROS_PYTHON, ThesisRobot, free_port, ros_env

LOAD_SCRIPT = ROOT / "scripts" / "ros1_robot" / "load_publishers.py"


def blackbox(config: Path, port: int, log: Path) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if k not in ("ROS_MASTER_URI",)}
    with log.open("wb") as out:
        return subprocess.Popen([*BLACKBOX, "run", "--config", str(config), "--source",
                                 f"ros1://127.0.0.1:{port}", "--quiet"],
                                stdout=out, stderr=subprocess.STDOUT, env=env, cwd=ROOT)


def thesis_phases(seconds: float, warmup: float, work: Path) -> list[Usage]:
    out: list[Usage] = []
    with ThesisRobot(free_port(), log_dir=work / "thesis") as robot:
        robot.start()
        hz = subprocess.Popen(["rostopic", "hz", "/usb_cam/image_raw"],
                              env=ros_env(robot.port, robot.home),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            out.append(measure(hz, "rostopic hz /usb_cam/image_raw", warmup, seconds))
        finally:
            stop(hz)
        log = work / "blackbox-thesis.log"
        bb = blackbox(THESIS_CONFIG, robot.port, log)
        try:
            usage = measure(bb, "blackbox run, 10 thesis observers (tests 11-20)", warmup,
                            seconds)
        finally:
            stop(bb)
        rate = summary_rate(log)
        if rate is not None:
            usage.note = f"received {rate:.1f} msg/s (the robot publishes {15 + 33.3 + 15:.1f})"
        out.append(usage)
    return out


def load_phase(seconds: float, warmup: float, work: Path, topics: int, rate: float,
               processes: int) -> list[Usage]:
    robot = ThesisRobot(free_port(), log_dir=work / "load")
    robot.start_master()
    per = topics // processes
    names = [f"/load{i}" for i in range(processes)]
    pubs = [subprocess.Popen([ROS_PYTHON, str(LOAD_SCRIPT), "--name", n, "--topics", str(per),
                              "--rate", str(rate)], env=robot.env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True) for n in names]
    config = work / "load.yaml"
    lines = ["version: 1", "robot: {id: load}", "observers:"]
    for n in names:
        for i in range(per):
            lines.append(f"  - {{type: hz, topic: {n}/t{i}, filter: {{type: mean, window_size: "
                         f"50, deviation: std_deviation}}, states: [{{number: 1, name: ok, "
                         f"period: {{value: {{type: gauss, mean: {1 / rate}, "
                         f"std_deviation: {0.5 / rate}}}}}}}]}}")
    config.write_text("\n".join(lines) + "\n")
    out: list[Usage] = []
    try:
        robot.wait_registered(names)
        log = work / "blackbox-load.log"
        bb = blackbox(config, robot.port, log)
        try:
            usage = measure(bb, f"blackbox run, {per * processes} hz observers", warmup,
                            seconds)
            procs = [psutil.Process(p.pid) for p in pubs]
            for proc in procs:
                proc.cpu_percent(None)
            time.sleep(2.0)
            pub_cpu = sum(proc.cpu_percent(None) for proc in procs)
        finally:
            stop(bb)
        received = summary_rate(log)
        if received is not None:
            usage.note = (f"{per * processes} topics x {rate:g} Hz from {processes} rospy "
                          f"processes: received {received:.0f} msg/s of "
                          f"{per * processes * rate:.0f} offered; publishers used "
                          f"{pub_cpu:.0f} % CPU")
        out.append(usage)
    finally:
        for p in pubs:
            with_suppress_kill(p)
        robot.stop()
    return out


def with_suppress_kill(proc: subprocess.Popen[bytes]) -> None:
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        proc.kill()
        proc.wait()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="measuring window")
    parser.add_argument("--warmup", type=float, default=5.0)
    parser.add_argument("--topics", type=int, default=100)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--processes", type=int, default=4)
    parser.add_argument("--skip-load", action="store_true")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="ros1-bench-") as tmp:
        work = Path(tmp)
        rows = thesis_phases(args.seconds, args.warmup, work)
        if not args.skip_load:
            rows += load_phase(args.seconds, args.warmup, work, args.topics, args.rate,
                               args.processes)
    rows.append(Usage("thesis black box (Raspberry Pi 3, thesis section 6.2.2)", 32.5, 142.0,
                      0.0, "as reported, not measured here"))
    print_usage(rows)
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
