"""``blackbox demo``: the simulated thesis robot with random faults, watched from the station.

By default the black box and the station run as two processes that talk only over DDS
(loopback): the black box watches the simulated robot, records its health and publishes
UCMS health messages; ``blackbox station`` follows it and serves the web station on
http://127.0.0.1:8080. The demo makes a demo-only admin account with a fresh random
password for every run and prints it with the URL; it runs until Ctrl-C (``--duration``
for scripts). ``--fast`` instead runs five simulated minutes in-process in a few seconds,
printing state changes.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from blackbox.app import RunOptions, build, graceful_interrupts
from blackbox.transport.auth import station_trusted_by

DEMO_CONFIG = Path(__file__).resolve().parent.parent / "configs" / "thesis-extended.yaml"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("demo", help="simulated thesis robot with injected faults, watched live",
                       description="Run the black box on the simulated thesis robot while a "
                       "seeded random fault campaign breaks it, and the web station follows it "
                       "over DDS.")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="seconds to run (default: until Ctrl-C; 300 simulated seconds with "
                   "--fast)")
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
                   help="directory for the health log, JSON lines, ground truth and the "
                   "station's database")
    p.add_argument("--bind", default="127.0.0.1:8080", metavar="HOST:PORT",
                   help="address of the web station (default 127.0.0.1:8080)")
    p.set_defaults(func=demo_command)


def demo_command(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    if args.fast:
        return fast_demo(args, out)
    return two_process_demo(args, out)


ROS1_ROBOT = Path(__file__).resolve().parents[3] / "scripts" / "ros1_robot" / "inject.py"
ROS1_CONFIG = Path(__file__).resolve().parent.parent / "configs" / "thesis.yaml"


def run_arguments(args: argparse.Namespace, out: Path, duration: float | None,
                  port: int | None = None, config: Path | None = None,
                  ros2_domain: int | None = None) -> list[str]:
    if ros2_domain is not None:
        robot = ["--config", str(config or ROS1_CONFIG), "--source", f"ros2:{ros2_domain}"]
    elif port is None:
        robot = ["--config", str(config or DEMO_CONFIG), "--source", "sim:thesis", "--faults",
                 "random", "--seed", str(args.seed), "--ground-truth",
                 str(out / "ground_truth.jsonl")]
    else:
        robot = ["--config", str(config or ROS1_CONFIG), "--source", f"ros1://127.0.0.1:{port}"]
    return [*robot, *(["--duration", str(duration)] if duration is not None else []),
            "--observations", str(out / "observations.jsonl"),
            "--diagnoses", str(out / "diagnoses.jsonl"), "--events", str(out / "events.jsonl"),
            "--record", str(out / "blackbox.db")]


def fast_demo(args: argparse.Namespace, out: Path) -> int:
    duration = 300.0 if args.duration is None else args.duration
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
        [sys.executable, str(ROS1_ROBOT), "--port", str(port), "--duration",
         str(args.duration if args.duration is not None else 24 * 3600.0),
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
         str(args.duration if args.duration is not None else 24 * 3600.0), "--seed",
         str(args.seed), "--truth", str(out / "ground_truth.jsonl"),
         "--log-dir", str(out / "ros2-logs")],
        stdout=(out / "robot.log").open("w"), stderr=subprocess.STDOUT)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def two_process_demo(args: argparse.Namespace, out: Path) -> int:
    # Ctrl-C and SIGTERM both stop the demo and everything it started, also when a script
    # started it in the background (which leaves SIGINT ignored).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _interrupt)
    domain = args.domain if args.domain is not None else 100 + os.getpid() % 100
    blackbox = [sys.executable, "-m", "blackbox"]
    processes: list[subprocess.Popen[bytes]] = []
    db = out / "station.db"
    user, password = demo_account(db)
    key, config = station_trusted_by(DEMO_CONFIG if args.source == "sim" else ROS1_CONFIG,
                                     out, "demo-station")
    ready = out / "station.url"
    ready.unlink(missing_ok=True)
    log = (out / "blackbox.log").open("w")
    station_log = (out / "station.log").open("w")
    box: subprocess.Popen[bytes] | None = None
    try:
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
        box = subprocess.Popen(
            [*blackbox, "run", *run_arguments(args, out, args.duration, port, config,
                                              ros2_domain),
             "--dds", "--domain", str(domain), "--quiet"], stdout=log, stderr=subprocess.STDOUT)
        processes.append(box)
        what = ("the simulated thesis robot" if port is None and ros2_domain is None else
                f"the ROS 1 thesis robot (:{port})" if port is not None else
                f"the ROS 2 thesis robot (domain {ros2_domain})")
        station = subprocess.Popen(
            [*blackbox, "station", "--db", str(db), "--key", str(key), "--domain", str(domain),
             "--bind",
             args.bind, "--ready-file", str(ready),
             *(["--duration", str(args.duration + 2.0)] if args.duration is not None else [])],
            stdout=station_log, stderr=subprocess.STDOUT)
        processes.insert(0, station)
        deadline = time.monotonic() + 60
        while not ready.exists() and station.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        if not ready.exists():
            print(f"demo: the station did not start; see {out}/station.log", file=sys.stderr)
            return 1
        url = ready.read_text().strip()
        print(f"demo: black box (pid {box.pid}) watching {what}, publishing on DDS domain "
              f"{domain}.\n"
              f"demo: station: {url}\n"
              f"demo:   log in as {user} with password {password}\n"
              f"demo:   (a demo-only admin account, made anew with a random password for "
              f"this run)\n"
              f"demo: {'Ctrl-C to stop' if args.duration is None else f'{args.duration:g} s'}."
              , file=sys.stderr, flush=True)
        station.wait()
        box.wait(timeout=10)
    except (KeyboardInterrupt, subprocess.TimeoutExpired):
        pass
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut cleanup
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        stop_all(processes)
        log.close()
        station_log.close()
    if box is None:
        return 1
    print(f"demo: black box exited with {box.returncode}; health log {out}/blackbox.db "
          f"(try: blackbox log query --db {out}/blackbox.db --kind failure), "
          f"black box output in {out}/blackbox.log, station's database {db}", file=sys.stderr)
    return 0 if box.returncode in (0, -signal.SIGINT) else 1


DEMO_USER = "demo-admin"


def demo_account(db: Path) -> tuple[str, str]:
    """The demo's admin account with a new random password (replacing the last run's)."""
    from blackbox.cli.station import open_databases
    from blackbox.station.auth import Role

    store, auth = open_databases(db)
    try:
        password = secrets.token_urlsafe(12)
        if auth.user(DEMO_USER) is None:
            auth.add_user(DEMO_USER, password, Role.ADMIN, by="demo")
        else:  # a new password (ending the last run's sessions); it may be the only admin
            auth.set_password(DEMO_USER, password, by="demo", address="local")
            auth.set_role(DEMO_USER, Role.ADMIN, by="demo", address="local")
    finally:
        auth.close()
        store.close()
    return DEMO_USER, password


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
