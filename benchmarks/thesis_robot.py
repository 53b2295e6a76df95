"""What a user of the thesis robot feels, measured side by side in one run on real ROS 1.

    .venv/bin/python benchmarks/thesis_robot.py overhead [--repeat 5] [--seconds 20]
        [--before SRC]
    .venv/bin/python benchmarks/thesis_robot.py latency [--faults 10]

The robot is the thesis robot on Debian's ROS 1 (roscore, /usb_cam 640x480 rgb8 at 15 Hz,
/audio_capture ~33 Hz, /Signal_generator 15 Hz; ``scripts/ros1_robot``).

``overhead``: per round, ``rostopic hz /usb_cam/image_raw`` and the black box with its
default settings (``blackbox run`` with no ``--config``: ``configs/thesis.yaml``, which
matches the robot) plus ``--record --dds`` run *at the same time*; both processes' CPU
(user+system over the same window, 100 % = one core) is read over one window, and the
ratio black box / rostopic hz printed, with the CPU of the robot's three nodes over the
same window (what watching costs the robot itself: liveness probes, counters). Rounds
are repeated; min/median/max are printed with the load average. The black box's
observations over the window are counted: a healthy robot must give no faulty one.
``--before SRC`` alternates every round with the black box from another ``src/``
directory (before/after in the same run).
The ``camera`` column says how the black box measured the camera's rate: ``counted``
(its publisher's ``getBusStats`` counters, possible while a robot node subscribes to it:
here ``/Signal_generator`` and ``rostopic hz``) or ``subscribed`` (its own connection,
the 900 kB bodies dropped by the kernel). rospy cannot report a byte counter past 2**31,
so on this robot the counters stop after about 150 s of camera images and the black box
subscribes from then on; ``--subscribed`` adds a variant that always subscribes
(``?counters=0``).

``latency``: the black box (default settings, ``--dds``) watches the robot while a
listener in this process reads ``C_Failure_Event`` from DDS; the camera node is killed
(SIGKILL) and the time from the kill to the failure event reaching the listener is the
end-to-end latency (detection + diagnosis + health mapping + DDS). The node is then
restarted and the robot left to recover before the next fault.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil

from support import BLACKBOX, ROOT, stop

sys.path.insert(0, str(ROOT / "scripts" / "ros1_robot"))
from inject import Injector
from robot import NODES, ThesisRobot, free_port, ros_env

CAMERA = "/usb_cam/image_raw"


PURE_PYTHON = "python"
"""A ``--variant`` query starting with this runs the black box with the Python receive path
(``BLACKBOX_PURE_PYTHON=1``), e.g. ``--variant python-subscribed=python?counters=0``."""


def _blackbox(robot: ThesisRobot, work: Path, domain: int, extra: list[str],
              src: Path | None = None, query: str = "") -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("ROS_MASTER_URI", "CYCLONEDDS_URI")}
    if src is not None:
        env["PYTHONPATH"] = str(src)
    if query.startswith(PURE_PYTHON):  # the receive path's Python fallback
        env["BLACKBOX_PURE_PYTHON"], query = "1", query.removeprefix(PURE_PYTHON)
    log = (work / "bb.log").open("wb")
    return subprocess.Popen([*BLACKBOX, "run", "--source",
                             f"ros1://127.0.0.1:{robot.port}{query}",
                             "--dds", "--domain", str(domain), "--quiet", *extra],
                            stdout=log, stderr=subprocess.STDOUT, env=env, cwd=ROOT)


def _cpu(p: psutil.Process) -> float:
    return float(sum(p.cpu_times()[:2]))


def camera_mode(log: Path) -> str:
    """How the black box measured the camera's rate at the end of a run, from its log:
    ``counted`` (the publisher's getBusStats counters), else ``subscribed``."""
    mode = "subscribed"
    for line in log.read_text(errors="replace").splitlines():
        if CAMERA in line and "own counters" in line:
            mode = "counted"
        elif CAMERA in line and "subscribing to measure" in line:
            mode = "subscribed"
    return mode


def overhead_round(robot: ThesisRobot, work: Path, seconds: float, warmup: float,
                   domain: int, src: Path | None, query: str | None = "") -> dict[str, Any]:
    """One window; ``query`` ``None`` runs ``rostopic hz`` alone (no black box)."""
    work.mkdir(parents=True, exist_ok=True)
    obs = work / "obs.jsonl"
    bb = None if query is None else _blackbox(
        robot, work, domain, ["--record", str(work / "health.db"), "--observations", str(obs)],
        src, query)
    hz = subprocess.Popen(["rostopic", "hz", CAMERA], env=ros_env(robot.port, robot.home),
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    watched = [hz] if bb is None else [hz, bb]
    try:
        procs = [psutil.Process(p.pid) for p in watched]
        nodes = [psutil.Process(pid) for name, pid in robot.pids().items()
                 if name in NODES]
        time.sleep(warmup)
        if any(p.poll() is not None for p in watched):
            raise RuntimeError(f"exited early; see {work / 'bb.log'}")
        t0, before = time.time(), [_cpu(p) for p in procs + nodes]
        time.sleep(seconds)
        t1, after = time.time(), [_cpu(p) for p in procs + nodes]
        rss = procs[-1].memory_info().rss / 1e6 if bb is not None else 0.0
        load = os.getloadavg()[0]
    finally:
        for p in watched:
            stop(p, timeout=15)
    used = [100 * (b - a) / (t1 - t0) for a, b in zip(before, after, strict=True)]
    hz_cpu, nodes_cpu = used[0], sum(used[len(procs):])
    row: dict[str, Any] = {"hz_cpu": hz_cpu, "nodes_cpu": nodes_cpu, "load": load,
                           "bb_cpu": None, "ratio": None, "rss_mb": None, "faulty": 0,
                           "observations": 0, "camera": "-"}
    if bb is None:
        return row
    faulty = total = 0
    for line in obs.read_text().splitlines():
        o = json.loads(line)
        if t0 <= o["time"] <= t1:
            total += 1
            faulty += bool(o["faulty"])
            if o["faulty"]:
                print(f"      faulty: {line[:300]}", flush=True)
    return {**row, "bb_cpu": used[1], "ratio": used[1] / hz_cpu, "rss_mb": rss,
            "faulty": faulty, "observations": total, "camera": camera_mode(work / "bb.log")}


def _shown(value: float | None, spec: str) -> str:
    """``value`` formatted, or a dash as wide for a window without a black box."""
    return "-".rjust(int(spec.split(".")[0])) if value is None else format(value, spec)


def overhead(args: argparse.Namespace) -> int:
    variants: list[tuple[str, Path | None, str | None]] = [("after", None, "")]
    if args.before is not None:
        variants.insert(0, ("before", args.before.resolve(), ""))
    if args.subscribed:
        variants.append(("after-subscribed", None, "?counters=0"))
    for spec in args.variant:
        label, _, query = spec.partition("=")
        variants.append((label, None, query))
    if args.robot_alone:
        variants.append(("no black box", None, None))
    rows: dict[str, list[dict[str, Any]]] = {label: [] for label, _, _ in variants}
    print(f"{'round':>5} {'variant':>20} {'blackbox':>9} {'rostopic hz':>11} {'ratio':>6} "
          f"{'RSS MB':>7} {'faulty/obs':>10} {'camera':>10} {'robot nodes':>11} {'load':>5}")
    with tempfile.TemporaryDirectory(prefix="thesis-bench-") as tmp, \
            ThesisRobot(free_port(), log_dir=Path(tmp) / "robot") as robot:
        robot.start()
        for r in range(args.repeat):
            for label, src, query in variants:
                row = overhead_round(robot, Path(tmp) / f"{label}{r}", args.seconds,
                                     args.warmup, args.domain, src, query)
                rows[label].append(row)
                print(f"{r:5d} {label:>20} {_shown(row['bb_cpu'], '8.2f')}% "
                      f"{row['hz_cpu']:10.2f}% {_shown(row['ratio'], '6.2f')} "
                      f"{_shown(row['rss_mb'], '7.1f')} "
                      f"{row['faulty']:>4.0f}/{row['observations']:<5.0f} "
                      f"{row['camera']:>10} {row['nodes_cpu']:10.2f}% {row['load']:5.2f}",
                      flush=True)
    for label, got in rows.items():
        nodes = statistics.median(x["nodes_cpu"] for x in got)
        ratios = sorted(x["ratio"] for x in got if x["ratio"] is not None)
        spread = (f"black box / rostopic hz over {len(got)} rounds: min {ratios[0]:.2f}  "
                  f"median {statistics.median(ratios):.2f}  max {ratios[-1]:.2f}; "
                  if ratios else "")
        print(f"{label}: {spread}robot nodes median {nodes:.2f} %"
              f"; faulty observations {sum(x['faulty'] for x in got):.0f}")
    return 0


def latency(args: argparse.Namespace) -> int:
    from blackbox.transport.participant import Bus, TransportSettings

    os.environ.pop("CYCLONEDDS_URI", None)
    results: list[float] = []
    with tempfile.TemporaryDirectory(prefix="thesis-latency-") as tmp, \
            ThesisRobot(free_port(), log_dir=Path(tmp) / "robot") as robot:
        robot.start()
        bus = Bus.open(TransportSettings(args.domain))
        reader = bus.reader("C_Failure_Event")
        bb = _blackbox(robot, Path(tmp), args.domain, [])
        try:
            time.sleep(args.warmup)
            injector = Injector(robot)
            for i in range(args.faults):
                reader.take(N=100_000)  # anything before the fault
                fault = injector.begin("kill", "/usb_cam")
                killed = time.time()
                seen: float | None = None
                deadline = time.monotonic() + args.timeout
                while seen is None and time.monotonic() < deadline:
                    for s in reader.take_iter(timeout=20_000_000):
                        info = getattr(s, "sample_info", None)
                        if info is not None and not info.valid_data:
                            continue
                        text = f"{s.A_failureDescription} {s.A_causeDescription}"
                        if "usb_cam" in text:
                            seen = time.time()
                            break
                injector.end(fault)
                robot.wait_registered(["/usb_cam"])
                if seen is None:
                    print(f"fault {i}: no failure event within {args.timeout} s", flush=True)
                else:
                    results.append(seen - killed)
                    print(f"fault {i}: kill -> failure event at the listener "
                          f"{1000 * (seen - killed):7.1f} ms  (load "
                          f"{os.getloadavg()[0]:.2f})", flush=True)
                time.sleep(args.recover)
        finally:
            stop(bb, timeout=15)
            bus.close()
    if results:
        ms = sorted(1000 * x for x in results)
        print(f"end-to-end fault -> remote listener over {len(ms)} of {args.faults} faults: "
              f"min {ms[0]:.0f} ms  median {statistics.median(ms):.0f} ms  max {ms[-1]:.0f} ms")
    return 0 if len(results) == args.faults else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    o = sub.add_parser("overhead")
    o.add_argument("--repeat", type=int, default=5)
    o.add_argument("--seconds", type=float, default=20.0)
    o.add_argument("--warmup", type=float, default=6.0)
    o.add_argument("--before", type=Path, metavar="SRC")
    o.add_argument("--variant", action="append", default=[], metavar="LABEL=QUERY",
                   help="also the black box with this source query, e.g. "
                        "'coalesced=?counters=0&coalesce=0.05'")
    o.add_argument("--robot-alone", action="store_true",
                   help="also a window with rostopic hz alone: the robot nodes' CPU "
                        "without a black box")
    o.add_argument("--subscribed", action="store_true",
                   help="also run the black box with ?counters=0: the camera subscribed "
                        "(bodies dropped by the kernel) instead of read from the counters")
    lat = sub.add_parser("latency")
    lat.add_argument("--faults", type=int, default=10)
    lat.add_argument("--warmup", type=float, default=8.0)
    lat.add_argument("--recover", type=float, default=6.0)
    lat.add_argument("--timeout", type=float, default=10.0)
    for p in (o, lat):
        p.add_argument("--domain", type=int, default=100 + os.getpid() % 50)
    args = parser.parse_args(argv)
    return overhead(args) if args.what == "overhead" else latency(args)


if __name__ == "__main__":
    raise SystemExit(main())
