"""The black box over real TCPROS as the load grows: CPU per message, received vs
published, and the hz observer's reading against the true rate, side by side in one run.

    .venv/bin/python benchmarks/ros1_scaling.py [--seconds 10] [--warmup 4]
        [--cases 1x100,10x100,50x100,200x100,1x1000,1x5000,1x20000] [--repeat 1]
        [--json out.json]

Each case ``TxR`` starts a real roscore and rospy publishers (``benchmarks/ros1/
paced_publisher.py``, at most 50 topics or 5,000 msg/s per process) publishing ``T``
std_msgs/Float64 topics at ``R`` Hz, then ``blackbox run`` with one hz observer per topic
(window: 50 periods, or one second of messages above 50 Hz) on
``--source ros1://127.0.0.1:PORT --observations FILE``. Over the same window it reads:

- CPU of the black box (user+system of the process / wall time; 100 % = one core) and CPU
  per message received;
- messages received (``blackbox run``'s closing summary) against messages published
  (the publishers' own counters);
- every hz reading (``rate_hz``) against the publisher's true rate over the same second,
  and how many observations were faulty (a healthy run has none) and how many readings
  counted a silence as a provisional period (``prov``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import psutil

from support import BLACKBOX, ROOT, stop

sys.path.insert(0, str(ROOT / "scripts" / "ros1_robot"))
from robot import ROS_PYTHON, ThesisRobot, free_port

PUBLISHER = ROOT / "benchmarks" / "ros1" / "paced_publisher.py"


@dataclass
class Case:
    topics: int
    rate: float
    seconds: float
    bb_cpu_percent: float
    publishers_cpu_percent: float
    published_per_s: float
    received_per_s: float
    us_cpu_per_message: float
    rate_error_median_pct: float
    rate_error_max_pct: float
    readings: int
    faulty: int
    provisional: int
    load_average: float


def _publishers(robot: ThesisRobot, topics: int, rate: float, work: Path
                ) -> list[tuple[subprocess.Popen[bytes], Path, int]]:
    per_proc = max(1, min(50, int(5000 // rate))) if rate <= 5000 else 1
    procs: list[tuple[subprocess.Popen[bytes], Path, int]] = []
    for p, start in enumerate(range(0, topics, per_proc)):
        n = min(per_proc, topics - start)
        out = work / f"pub{p}.txt"
        with out.open("wb") as f:
            proc = subprocess.Popen(
                [ROS_PYTHON, str(PUBLISHER), "--name", f"/pace{p}", "--topics", str(n),
                 "--rate", str(rate), "--prefix", f"/pace{p}/t"],
                env=robot.env, stdout=f, stderr=subprocess.DEVNULL, start_new_session=True)
        procs.append((proc, out, n))
    robot.wait_registered([f"/pace{p}" for p in range(len(procs))])
    return procs


def _sent(out: Path) -> list[tuple[float, int]]:
    rows = []
    for line in out.read_text().splitlines():
        parts = line.split()
        if len(parts) == 2:
            rows.append((float(parts[0]), int(parts[1])))
    return rows


def _sent_between(rows: list[tuple[float, int]], t0: float, t1: float) -> float:
    """Messages per topic sent in [t0, t1], interpolating the once-a-second counter."""
    def at(t: float) -> float:
        for (ta, na), (tb, nb) in itertools.pairwise(rows):
            if ta <= t <= tb:
                return na + (nb - na) * (t - ta) / (tb - ta)
        if rows and t > rows[-1][0]:
            return float(rows[-1][1])  # a publisher too busy to report: its last count
        raise ValueError(f"no publisher count around {t:.3f}")
    return at(t1) - at(t0)


def _config(path: Path, names: list[str], rate: float) -> None:
    window = 50 if rate <= 50 else int(rate)
    lines = ["version: 1", "robot: {id: scaling}", "observers:"]
    for name in names:
        lines.append(
            f"  - {{type: hz, topic: {name}, filter: {{type: mean, window_size: {window}, "
            f"deviation: std_deviation}}, states: [{{number: 1, name: ok, period: {{value: "
            f"{{type: gauss, mean: {1 / rate:.9f}, std_deviation: {0.02 / rate:.9f}}}}}}}]}}")
    path.write_text("\n".join(lines) + "\n")


def run_case(topics: int, rate: float, seconds: float, warmup: float, work: Path,
             src: Path | None = None) -> Case:
    work.mkdir(parents=True, exist_ok=True)
    robot = ThesisRobot(free_port(), log_dir=work)
    robot.start_master()
    pubs: list[tuple[subprocess.Popen[bytes], Path, int]] = []
    try:
        pubs = _publishers(robot, topics, rate, work)
        names = [f"/pace{p}/t{i}" for p, (_, _, n) in enumerate(pubs) for i in range(n)]
        config, obs, log = work / "scaling.yaml", work / "obs.jsonl", work / "bb.log"
        _config(config, names, rate)
        env = {k: v for k, v in os.environ.items() if k != "ROS_MASTER_URI"}
        if src is not None:
            env["PYTHONPATH"] = str(src)
        with log.open("wb") as out:
            bb = subprocess.Popen([*BLACKBOX, "run", "--config", str(config), "--source",
                                   f"ros1://127.0.0.1:{robot.port}", "--observations",
                                   str(obs), "--quiet"], stdout=out,
                                  stderr=subprocess.STDOUT, env=env, cwd=ROOT)
        try:
            p = psutil.Process(bb.pid)
            pp = [psutil.Process(proc.pid) for proc, _, _ in pubs]
            time.sleep(warmup)
            w0, c0 = time.time(), sum(p.cpu_times()[:2])
            pc0 = sum(sum(q.cpu_times()[:2]) for q in pp)
            time.sleep(seconds)
            w1, c1 = time.time(), sum(p.cpu_times()[:2])
            pc1 = sum(sum(q.cpu_times()[:2]) for q in pp)
            load = os.getloadavg()[0]
            time.sleep(1.2)  # one more publisher report after the window
        finally:
            stop(bb)
        text = log.read_text(errors="replace")
        m = re.search(r"([\d.,]+) s observed, ([\d,]+) messages", text)
        if not m:
            raise RuntimeError(f"no summary from blackbox run:\n{text[-2000:]}")
        received = int(m.group(2).replace(",", "")) / float(m.group(1).replace(",", ""))
        published = sum(n * _sent_between(_sent(out), w0, w1) for _, out, n in pubs) / (w1 - w0)
        errors: list[float] = []
        faulty = provisional = 0
        rows = {out: _sent(out) for _, out, _ in pubs}
        topic_rows = {name: rows[pubs[p][1]] for p, (_, _, n) in enumerate(pubs)
                      for name in [f"/pace{p}/t{i}" for i in range(n)]}
        window = (50 / rate) if rate <= 50 else 1.0
        for line in obs.read_text().splitlines():
            o = json.loads(line)
            t = o["time"]
            if o.get("observer") != "hz" or not (w0 <= t <= w1):
                continue
            faulty += bool(o["faulty"])
            provisional += "provisional" in o.get("message", "")
            hz = o["values"].get("rate_hz")
            if hz is None:
                continue
            true = _sent_between(topic_rows[o["resource"]["topic"]], t - window, t) / window
            errors.append(100.0 * abs(hz - true) / true)
        cpu = 100.0 * (c1 - c0) / (w1 - w0)
        return Case(topics, rate, w1 - w0, cpu, 100.0 * (pc1 - pc0) / (w1 - w0), published,
                    received, 1e6 * (c1 - c0) / max(1.0, received * (w1 - w0)),
                    statistics.median(errors) if errors else float("nan"),
                    max(errors) if errors else float("nan"), len(errors), faulty, provisional,
                    load)
    finally:
        for proc, _, _ in pubs:
            stop(proc, group=True)
        robot.stop()


def _print(name: str, c: Case) -> None:
    print(f"{name:>17} {c.bb_cpu_percent:6.1f}% {c.publishers_cpu_percent:6.1f}% "
          f"{c.published_per_s:10.0f} {c.received_per_s:10.0f} "
          f"{c.received_per_s / c.published_per_s:8.3f} {c.us_cpu_per_message:7.1f} "
          f"{c.rate_error_median_pct:8.2f} / {c.rate_error_max_pct:7.2f} "
          f"{c.faulty:3d}/{c.readings:<3d} {c.provisional:4d} {c.load_average:5.2f}",
          flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--warmup", type=float, default=4.0)
    parser.add_argument("--cases", default="1x100,10x100,50x100,200x100,1x1000,1x5000,1x20000")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--before", type=Path, metavar="SRC",
                        help="also run every case with the black box from this src/ "
                             "directory (e.g. an older checkout), alternating, same window")
    args = parser.parse_args(argv)
    cases = [(int(t), float(r)) for t, r in (c.split("x") for c in args.cases.split(","))]
    results: list[Case] = []
    print(f"{'case':>17} {'bb CPU':>7} {'pub CPU':>7} {'published':>10} {'received':>10} "
          f"{'recv/pub':>8} {'us/msg':>7} {'rate err med/max %':>18} {'faulty':>7} "
          f"{'prov':>4} {'load':>5}")
    with tempfile.TemporaryDirectory(prefix="ros1-scaling-") as tmp:
        variants: list[tuple[str, Path | None]] = [("", None)]
        if args.before is not None:
            variants = [("before ", args.before.resolve()), ("", None)]
        for r in range(args.repeat):
            for topics, rate in cases:
                for label, src in variants:
                    c = run_case(topics, rate, args.seconds, args.warmup,
                                 Path(tmp) / f"{label.strip()}{topics}x{rate:g}-{r}", src)
                    results.append(c)
                    _print(f"{label}{topics}x{rate:g}", c)
    if args.json:
        args.json.write_text(json.dumps([asdict(c) for c in results], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
