"""The black box over real TCPROS as the load grows: CPU per message, received vs
published, and the hz observer's reading against the true rate, side by side in one run.

    .venv/bin/python benchmarks/ros1_scaling.py [--seconds 10] [--warmup 4]
        [--cases 1x100,10x100,50x100,200x100,1x1000,1x5000,1x20000] [--repeat 1]
        [--options ';readers=1;coalesce=0.001'] [--before SRC] [--json out.json]

Each case ``TxR`` starts a real roscore and rospy publishers (``benchmarks/ros1/
paced_publisher.py``, at most 50 topics or 5,000 msg/s per process) publishing ``T``
std_msgs/Float64 topics at ``R`` Hz; ``TxRf`` uses the fast publisher instead
(``benchmarks/ros1/fast_publisher.py``: real master registration, XML-RPC and TCPROS
handshake, pre-built frames written in one send per tick, at most ``--fast-load`` msg/s
per process), which can offer 100k msg/s here where rospy stops near 6-11k. Then
``blackbox run`` with one hz observer per topic (window: 50 periods, or one second of
messages above 50 Hz) on ``--source ros1://127.0.0.1:PORT?OPTIONS --observations FILE``,
once per ``--options`` entry (and with ``--before``, also from an older ``src/``).
Over the same window it reads:

- CPU of the black box (user+system of the process and its reader processes / wall time;
  100 % = one core) and CPU per message received;
- messages published per second over the window (the publishers' own counters; below the
  offered rate when a publisher cannot keep pace or the black box does not take the data
  and TCP pushes back), received per second over the black box's whole run, and
  ``got/sent``: messages the black box counted (its closing summary) over the messages the
  publishers wrote to its connections (their ``getBusStats``, asked just before the black
  box is stopped, so a few more may still arrive: slightly above 1 is normal);
- every hz reading (``rate_hz``) against the publisher's true rate over the same second,
  and how many observations were faulty (a healthy run has none) and how many readings
  counted a silence as a provisional period (``prov``).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
import xmlrpc.client
from dataclasses import asdict, dataclass
from pathlib import Path

import psutil

from support import BLACKBOX, ROOT, stop

sys.path.insert(0, str(ROOT / "scripts" / "ros1_robot"))
from robot import ROS_PYTHON, ThesisRobot, free_port

PUBLISHER = ROOT / "benchmarks" / "ros1" / "paced_publisher.py"
FAST_PUBLISHER = ROOT / "benchmarks" / "ros1" / "fast_publisher.py"


@dataclass
class Case:
    topics: int
    rate: float
    publisher: str
    variant: str
    seconds: float
    bb_cpu_percent: float
    publishers_cpu_percent: float
    published_per_s: float
    received_per_s: float
    received_of_sent: float
    us_cpu_per_message: float
    rate_error_median_pct: float
    rate_error_max_pct: float
    readings: int
    faulty: int
    provisional: int
    load_average: float


def _publishers(robot: ThesisRobot, topics: int, rate: float, work: Path, fast: bool,
                fast_load: float) -> list[tuple[subprocess.Popen[bytes], Path, int]]:
    if fast:
        per_proc = max(1, int(fast_load // rate))
    else:
        per_proc = max(1, min(50, int(5000 // rate))) if rate <= 5000 else 1
    procs: list[tuple[subprocess.Popen[bytes], Path, int]] = []
    for p, start in enumerate(range(0, topics, per_proc)):
        n = min(per_proc, topics - start)
        out = work / f"pub{p}.txt"
        args = ["--name", f"/pace{p}", "--topics", str(n), "--rate", str(rate), "--prefix",
                f"/pace{p}/t"]
        cmd = ([sys.executable, str(FAST_PUBLISHER), "--master", robot.master_uri, *args]
               if fast else [ROS_PYTHON, str(PUBLISHER), *args])
        with out.open("wb") as f:
            proc = subprocess.Popen(cmd, env=robot.env, stdout=f, stderr=subprocess.DEVNULL,
                                    start_new_session=True)
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


PURE_PYTHON = "python"
"""An ``--options`` entry: the defaults, with the Python receive path instead of the native
loop (``BLACKBOX_PURE_PYTHON=1``)."""


def run_case(topics: int, rate: float, seconds: float, warmup: float, work: Path,
             src: Path | None = None, options: str = "", fast: bool = False,
             fast_load: float = 50_000.0, variant: str = "") -> Case:
    work.mkdir(parents=True, exist_ok=True)
    robot = ThesisRobot(free_port(), log_dir=work)
    robot.start_master()
    pubs: list[tuple[subprocess.Popen[bytes], Path, int]] = []
    try:
        pubs = _publishers(robot, topics, rate, work, fast, fast_load)
        names = [f"/pace{p}/t{i}" for p, (_, _, n) in enumerate(pubs) for i in range(n)]
        config, obs, log = work / "scaling.yaml", work / "obs.jsonl", work / "bb.log"
        _config(config, names, rate)
        env = {k: v for k, v in os.environ.items() if k != "ROS_MASTER_URI"}
        if src is not None:
            env["PYTHONPATH"] = str(src)
        if options == PURE_PYTHON:  # the receive path's Python fallback
            env["BLACKBOX_PURE_PYTHON"], options = "1", ""
        spec = f"ros1://127.0.0.1:{robot.port}"
        if options:
            spec += f"?{options}"
        with log.open("wb") as out:
            bb = subprocess.Popen([*BLACKBOX, "run", "--config", str(config), "--source",
                                   spec, "--observations",
                                   str(obs), "--quiet"], stdout=out,
                                  stderr=subprocess.STDOUT, env=env, cwd=ROOT)
        try:
            p = psutil.Process(bb.pid)
            pp = [psutil.Process(proc.pid) for proc, _, _ in pubs]
            time.sleep(warmup)
            family = [p, *p.children(recursive=True)]
            w0, c0 = time.time(), _cpu(family)
            pc0 = _cpu(pp)
            time.sleep(seconds)
            w1, c1 = time.time(), _cpu(family)
            pc1 = _cpu(pp)
            load = os.getloadavg()[0]
            time.sleep(1.2)  # one more publisher report after the window
            sent = _sent_to_subscribers(robot, len(pubs))
        finally:
            stop(bb)
        text = log.read_text(errors="replace")
        m = re.search(r"([\d.,]+) s observed, ([\d,]+) messages", text)
        if not m:
            raise RuntimeError(f"no summary from blackbox run:\n{text[-2000:]}")
        got = int(m.group(2).replace(",", ""))
        received = got / float(m.group(1).replace(",", ""))
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
            try:
                true = _sent_between(topic_rows[o["resource"]["topic"]], t - window, t) / window
            except ValueError:  # a window reaching back before the publisher started
                continue
            errors.append(100.0 * abs(hz - true) / true)
        cpu = 100.0 * (c1 - c0) / (w1 - w0)
        return Case(topics, rate, "fast" if fast else "rospy", variant, w1 - w0, cpu,
                    100.0 * (pc1 - pc0) / (w1 - w0), published,
                    received, got / max(1, sent), 1e6 * (c1 - c0) / max(1.0, received * (w1 - w0)),
                    statistics.median(errors) if errors else float("nan"),
                    max(errors) if errors else float("nan"), len(errors), faulty, provisional,
                    load)
    finally:
        for proc, _, _ in pubs:
            stop(proc, group=True)
        robot.stop()


def _sent_to_subscribers(robot: ThesisRobot, publishers: int) -> int:
    """Messages the publishers wrote to their subscriber connections (the black box's)
    since those opened, from their own ``getBusStats``."""
    total = 0
    master = xmlrpc.client.ServerProxy(robot.master_uri)
    for p in range(publishers):
        code, _, uri = master.lookupNode("/scaling", f"/pace{p}")
        if code != 1:
            continue
        stats = xmlrpc.client.ServerProxy(uri).getBusStats("/scaling")
        for _topic, _bytes, conns in stats[2][0]:
            total += sum(int(c[2]) for c in conns)
    return total


def _cpu(procs: list[psutil.Process]) -> float:
    """User+system seconds of ``procs`` (one that exited counts nothing)."""
    total = 0.0
    for q in procs:
        with contextlib.suppress(psutil.Error):
            total += sum(q.cpu_times()[:2])
    return total


def _print(name: str, c: Case) -> None:
    print(f"{name:>28} {c.bb_cpu_percent:6.1f}% {c.publishers_cpu_percent:6.1f}% "
          f"{c.published_per_s:10.0f} {c.received_per_s:10.0f} "
          f"{c.received_of_sent:8.3f} {c.us_cpu_per_message:7.1f} "
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
    parser.add_argument("--options", default="",
                        help="';'-separated source options to run every case with, e.g. "
                             "';readers=1;coalesce=0.001' (empty entry: the defaults; "
                             "'python': the defaults with the Python receive path)")
    parser.add_argument("--fast-load", type=float, default=50_000.0,
                        help="msg/s per fast publisher process")
    args = parser.parse_args(argv)
    cases = []
    for spec in args.cases.split(","):
        t, r = spec.split("x")
        fast = r.endswith("f")
        cases.append((int(t), float(r.removesuffix("f")), fast))
    results: list[Case] = []
    print(f"{'case':>28} {'bb CPU':>7} {'pub CPU':>7} {'published':>10} {'received':>10} "
          f"{'got/sent':>8} {'us/msg':>7} {'rate err med/max %':>18} {'faulty':>7} "
          f"{'prov':>4} {'load':>5}")
    print(f"load average at start: {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory(prefix="ros1-scaling-") as tmp:
        variants: list[tuple[str, Path | None, str]] = [
            (f"{o} " if o else "", None, o) for o in args.options.split(";")]
        if args.before is not None:
            variants.insert(0, ("before ", args.before.resolve(), ""))
        for r in range(args.repeat):
            for topics, rate, fast in cases:
                for label, src, n in variants:
                    name = f"{label}{topics}x{rate:g}{'f' if fast else ''}"
                    c = run_case(topics, rate, args.seconds, args.warmup,
                                 Path(tmp) / f"{name.replace(' ', '-')}-{r}", src, n, fast,
                                 args.fast_load, label.strip())
                    results.append(c)
                    _print(name, c)
    if args.repeat > 1:
        print("\nover the repeats (runs with any faulty reading / runs; worst max error):")
        groups: dict[tuple[int, float, str, str], list[Case]] = {}
        for c in results:
            groups.setdefault((c.topics, c.rate, c.publisher, c.variant), []).append(c)
        for (t, rate, pub, variant), cs in groups.items():
            bad = sum(1 for c in cs if c.faulty)
            worst = max(c.rate_error_max_pct for c in cs)
            loads = [c.load_average for c in cs]
            print(f"  {variant or 'default'} {t}x{rate:g} {pub}: {bad}/{len(cs)} runs faulty, "
                  f"max error per run {', '.join(f'{c.rate_error_max_pct:.2f}' for c in cs)} "
                  f"% (worst {worst:.2f} %), load {min(loads):.1f}-{max(loads):.1f}")
    if args.json:
        args.json.write_text(json.dumps([asdict(c) for c in results], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
