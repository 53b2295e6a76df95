"""``blackbox demo``: the simulated thesis robot with random faults, watched live.

By default the black box and the station run as two processes that talk only over DDS
(loopback): the black box watches the simulated robot, records its health and publishes
UCMS health messages; ``blackbox listen`` shows what a remote station sees. ``--fast``
instead runs five simulated minutes in-process in a few seconds, printing state changes.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from blackbox.app import RunOptions, build, graceful_interrupts

DEMO_CONFIG = Path(__file__).resolve().parent.parent / "configs" / "thesis-extended.yaml"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("demo", help="simulated thesis robot with injected faults, watched live",
                       description="Run the black box on the simulated thesis robot while a "
                       "seeded random fault campaign breaks it, and a station listens over DDS.")
    p.add_argument("--duration", type=float, default=60.0, metavar="S",
                   help="seconds to run (default 60; 300 simulated seconds with --fast)")
    p.add_argument("--fast", action="store_true",
                   help="simulated clock, in one process: five robot minutes in a few seconds")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--source", choices=["sim", "ros1", "ros2"], default="sim",
                   help="sim: the simulated thesis robot (default); ros1: the real thesis robot "
                   "as rospy nodes under Debian's ROS 1 (scripts/ros1_robot), faults injected "
                   "on the real processes; ros2: the same as rclpy nodes on ROS 2 "
                   "(scripts/ros2_robot, needs the ros-rclpy wheels of the test extra)")
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


ROS1_ROBOT = Path(__file__).resolve().parents[3] / "scripts" / "ros1_robot" / "inject.py"
ROS1_CONFIG = Path(__file__).resolve().parent.parent / "configs" / "thesis.yaml"


def run_arguments(args: argparse.Namespace, out: Path, duration: float,
                  port: int | None = None, ros2_domain: int | None = None) -> list[str]:
    if ros2_domain is not None:
        robot = ["--config", str(ROS1_CONFIG), "--source", f"ros2:{ros2_domain}"]
    elif port is None:
        robot = ["--config", str(DEMO_CONFIG), "--source", "sim:thesis", "--faults", "random",
                 "--seed", str(args.seed), "--ground-truth", str(out / "ground_truth.jsonl")]
    else:
        robot = ["--config", str(ROS1_CONFIG), "--source", f"ros1://127.0.0.1:{port}"]
    return [*robot, "--duration", str(duration),
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


def start_ros1_robot(args: argparse.Namespace, out: Path) -> tuple[subprocess.Popen[bytes], int]:
    """roscore, the three thesis nodes and the fault injector, on a free loopback port."""
    if not ROS1_ROBOT.exists() or not Path("/usr/bin/roscore").exists():
        raise SystemExit("demo --source ros1 needs a source checkout (scripts/ros1_robot) and "
                         "Debian's ROS 1 (make system-deps)")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    robot = subprocess.Popen(
        [sys.executable, str(ROS1_ROBOT), "--port", str(port), "--duration", str(args.duration),
         "--seed", str(args.seed), "--truth", str(out / "ground_truth.jsonl"),
         "--log-dir", str(out / "ros1-logs")],
        stdout=(out / "robot.log").open("w"), stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and robot.poll() is None:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                break
        time.sleep(0.2)
    return robot, port


ROS2_ROBOT = ROS1_ROBOT.parent.parent / "ros2_robot" / "inject.py"


def start_ros2_robot(args: argparse.Namespace, out: Path, domain: int
                     ) -> subprocess.Popen[bytes]:
    """The three rclpy thesis nodes and their fault injector on ROS 2 domain ``domain``."""
    if not ROS2_ROBOT.exists():
        raise SystemExit("demo --source ros2 needs a source checkout (scripts/ros2_robot)")
    if importlib.util.find_spec("rclpy") is None:
        raise SystemExit("demo --source ros2 needs the ros-rclpy wheels (pip install -e '.[test]')")
    return subprocess.Popen(
        [sys.executable, str(ROS2_ROBOT), "--domain", str(domain), "--duration",
         str(args.duration), "--seed", str(args.seed), "--truth", str(out / "ground_truth.jsonl"),
         "--log-dir", str(out / "ros2-logs")],
        stdout=(out / "robot.log").open("w"), stderr=subprocess.STDOUT)


def two_process_demo(args: argparse.Namespace, out: Path) -> int:
    domain = args.domain if args.domain is not None else 100 + os.getpid() % 100
    blackbox = [sys.executable, "-m", "blackbox"]
    processes: list[subprocess.Popen[bytes]] = []
    port = ros2_domain = None
    if args.source == "ros1":
        ros1, port = start_ros1_robot(args, out)
        processes.append(ros1)
        time.sleep(2.0)  # let the nodes register before the black box looks
    elif args.source == "ros2":
        ros2_domain = (domain + 1) % 233
        processes.append(start_ros2_robot(args, out, ros2_domain))
        deadline = time.monotonic() + 30  # until the injector says the nodes are up
        while (time.monotonic() < deadline and processes[-1].poll() is None
               and not (out / "robot.log").read_text().strip()):
            time.sleep(0.2)
    log = (out / "blackbox.log").open("w")
    box = subprocess.Popen(
        [*blackbox, "run", *run_arguments(args, out, args.duration, port, ros2_domain), "--dds",
         "--domain", str(domain), "--quiet"], stdout=log, stderr=subprocess.STDOUT)
    what = ("the simulated thesis robot" if port is None and ros2_domain is None else
            f"the ROS 1 thesis robot (:{port})" if port is not None else
            f"the ROS 2 thesis robot (domain {ros2_domain})")
    print(f"demo: black box (pid {box.pid}) watching {what}, publishing on DDS domain "
          f"{domain}; station below. Ctrl-C to stop.", file=sys.stderr)
    station = subprocess.Popen([*blackbox, "listen", "--domain", str(domain),
                                "--duration", str(args.duration + 2.0)])
    processes += [station, box]
    try:
        station.wait()
        box.wait(timeout=10)
    except (KeyboardInterrupt, subprocess.TimeoutExpired):
        pass
    finally:
        stop_all(processes)
        log.close()
    print(f"demo: black box exited with {box.returncode}; health log {out}/blackbox.db "
          f"(try: blackbox log query --db {out}/blackbox.db --kind failure), "
          f"black box output in {out}/blackbox.log", file=sys.stderr)
    return 0 if box.returncode == 0 else 1


def stop_all(processes: list[subprocess.Popen[bytes]], grace: float = 10.0) -> None:
    """Ask every process still running to stop (SIGINT), then kill what outlives ``grace``."""
    for proc in processes:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + grace
    for proc in processes:
        try:
            proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
