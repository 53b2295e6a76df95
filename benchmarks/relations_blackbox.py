"""What relation observers add to the whole black box: 10 signals at 100 Hz on real ROS 1.

    .venv/bin/python benchmarks/relations_blackbox.py [--seconds 30] [--repeat 3] [--learn 60]
                                                      [--before SRC]

A bare Debian ROS 1 master and two rospy processes publishing five ``std_msgs/Float64``
topics each at 100 Hz, every message one slow sine of the wall clock plus noise (so the ten
signals measure one motion, as redundant sensors do). ``blackbox run --source ros1://...``
watches them with each variant:

* ``hand``: what ``benchmarks/relations_cpu.py`` measures for the observers alone, now in
  the whole process (receive, decode, observe, diagnose): per topic ``hz``, ``timeout`` and
  a ``fields`` envelope, then the same plus one ``liveness`` observer per topic and a
  ``relation`` for each of the nine neighbouring pairs.
* ``learned`` (with ``--learn S`` > 0): ``blackbox learn`` watches the robot for S seconds;
  the file it writes; the same file without its ``relation`` and ``liveness`` observers
  (it then reads no value: rate-only topics, bodies dropped by the kernel); and that one
  plus a ``fields`` envelope per topic, which receives and decodes every message as the
  relations must. The relations are compared with the last.

Every round runs all variants at once, each its own ``blackbox run`` process watching the
same robot over the same window: this machine's cores run fast and slow in phases of a
minute or more (the same process measured 6.2 % in one window and 11.8 % in the next), so
variants measured one after the other compared phases, not code. CPU is each process's
user+system time over the window (100 % = one core), after a warm-up; the table gives
every round and the median of the per-round figures. Issue 22 item 5 asks that the
relations add at most 10 % to the black box. ``--before SRC`` runs every variant a second
time in each round with ``PYTHONPATH=SRC`` (an older ``src/``, e.g. from ``git archive``), so
two versions of the code are compared in one run on the same robot and learned file.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

from relations_cpu import baseline_entries, relation_entries
from support import BLACKBOX, ROOT, measure_together, stop, summary_rate

sys.path.insert(0, str(ROOT / "scripts" / "ros1_robot"))
from robot import ROS_PYTHON, ThesisRobot, free_port

LOAD_SCRIPT = ROOT / "scripts" / "ros1_robot" / "load_publishers.py"
PROCESSES = ("/wave0", "/wave1")
PER_PROCESS = 5
RATE = 100.0
TOPICS = [f"{p}/t{i}" for p in PROCESSES for i in range(PER_PROCESS)]
RELATION_KINDS = ("relation", "liveness")


def write_config(path: Path, entries: list[str]) -> Path:
    path.write_text("version: 1\nrobot: {id: wave}\nobservers:\n"
                    + "".join(f"  - {e}\n" for e in entries))
    return path


def without_relations(learned: Path, out: Path) -> int:
    """Write ``learned`` without its relation and liveness observers; how many it had."""
    data = yaml.safe_load(learned.read_text())
    kept = [o for o in data["observers"] if o.get("type") not in RELATION_KINDS]
    removed = len(data["observers"]) - len(kept)
    data["observers"] = kept
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return removed


def with_fields(stripped: Path, out: Path) -> None:
    """``stripped`` plus a ``fields`` envelope of every topic's ``data``: the black box
    then receives and decodes every message, as it must to relate them. The learned file
    without relations reads no value (the learner writes no band for a signal whose range
    depends on the operating mode), so the kernel drops the bodies and nothing is decoded;
    the difference between the two is the price of reading values at all, not of
    relations."""
    data = yaml.safe_load(stripped.read_text())
    data["observers"] += [yaml.safe_load(e) for e in baseline_entries(TOPICS, "data")
                          if e.startswith("{type: fields")]
    out.write_text(yaml.safe_dump(data, sort_keys=False))


def run_blackbox(config: Path, port: int, log: Path, src: Path | None = None
                 ) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if k != "ROS_MASTER_URI"}
    if src is not None:
        env["PYTHONPATH"] = str(src)
    with log.open("wb") as out:
        return subprocess.Popen([*BLACKBOX, "run", "--config", str(config), "--source",
                                 f"ros1://127.0.0.1:{port}", "--quiet"],
                                stdout=out, stderr=subprocess.STDOUT, env=env, cwd=ROOT)


def learn(port: int, seconds: float, out: Path, log: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "ROS_MASTER_URI"}
    with log.open("wb") as sink:
        done = subprocess.run([*BLACKBOX, "learn", "--source", f"ros1://127.0.0.1:{port}",
                               "--duration", str(seconds), "--discovery", "3", "--quiet",
                               "-o", str(out), "--robot-id", "wave"],
                              stdout=sink, stderr=subprocess.STDOUT, env=env, cwd=ROOT,
                              timeout=seconds + 120)
    if done.returncode != 0:
        raise RuntimeError(f"blackbox learn failed ({done.returncode}), see {log}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="measuring window")
    parser.add_argument("--warmup", type=float, default=5.0)
    parser.add_argument("--repeat", type=int, default=3, help="rounds of every variant")
    parser.add_argument("--learn", type=float, default=60.0,
                        help="seconds to learn for the learned pair (0: skip it)")
    parser.add_argument("--before", type=Path, default=None,
                        help="an older src/ to run every variant with as well")
    args = parser.parse_args(argv)
    if args.before is not None and not (args.before / "blackbox").is_dir():
        parser.error(f"--before {args.before}: no blackbox package in it")
    versions: list[tuple[str, Path | None]] = [("", None)]
    if args.before is not None:
        versions.insert(0, ("before: ", args.before.resolve()))
    load_start = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="relations-bb-") as tmp:
        work = Path(tmp)
        robot = ThesisRobot(free_port(), log_dir=work / "robot")
        robot.start_master()
        pubs = [subprocess.Popen([ROS_PYTHON, str(LOAD_SCRIPT), "--name", name, "--topics",
                                  str(PER_PROCESS), "--rate", str(RATE), "--wave"],
                                 env=robot.env, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL, start_new_session=True)
                 for name in PROCESSES]
        try:
            robot.wait_registered(list(PROCESSES))
            hand_base = "hand: hz, timeout, fields per topic"
            variants: list[tuple[str, Path, str | None]] = [
                (hand_base, write_config(work / "hand-base.yaml",
                                         baseline_entries(TOPICS, "data")), None),
                ("hand: + 10 liveness, 9 relation observers", write_config(
                    work / "hand-rel.yaml",
                    baseline_entries(TOPICS, "data") + relation_entries(TOPICS, "data")),
                 hand_base),
            ]
            if args.learn > 0:
                print(f"learning {args.learn:g} s ...", flush=True)
                learned = work / "learned.yaml"
                learn(robot.port, args.learn, learned, work / "learn.log")
                stripped = work / "learned-base.yaml"
                removed = without_relations(learned, stripped)
                decoded = work / "learned-fields.yaml"
                with_fields(stripped, decoded)
                variants += [
                    ("learned, without relation and liveness", stripped, None),
                    ("learned, without them, + a fields envelope per topic", decoded, None),
                    (f"learned ({removed} relation and liveness observers)", learned,
                     "learned, without them, + a fields envelope per topic"),
                ]
            runs = [(label + name, config, src, label + against if against else None)
                    for label, src in versions for name, config, against in variants]
            cpu: dict[str, list[float]] = {name: [] for name, _, _, _ in runs}
            rates: dict[str, list[float]] = {name: [] for name, _, _, _ in runs}
            against_of = {name: against for name, _, _, against in runs}
            for r in range(args.repeat):
                print(f"round {r + 1}/{args.repeat}: {len(runs)} black boxes at once ...",
                      flush=True)
                logs = {name: work / f"bb-{r}-{i}.log"
                        for i, (name, _, _, _) in enumerate(runs)}
                boxes: dict[str, subprocess.Popen[bytes]] = {}
                try:
                    for name, config, src, _ in runs:
                        boxes[name] = run_blackbox(config, robot.port, logs[name], src)
                    usage = measure_together(boxes, args.warmup, args.seconds)
                finally:
                    for bb in boxes.values():
                        stop(bb)
                for name in cpu:
                    cpu[name].append(usage[name].cpu_percent)
                    rate = summary_rate(logs[name])
                    if rate is not None:
                        rates[name].append(rate)
        finally:
            for p in pubs:
                stop(p, group=True)
            robot.stop()
    print(f"machine: {os.cpu_count()} cores, python {sys.version.split()[0]}; "
          f"{len(TOPICS)} topics x {RATE:g} Hz from {len(PROCESSES)} rospy processes; "
          f"{args.repeat} rounds x {args.seconds:g} s after {args.warmup:g} s warm-up; "
          f"load average {load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")
    print("| blackbox run with | CPU % of one core, rounds | median | received msg/s | added, "
          "median of the rounds |")
    print("|---|---|---|---|---|")
    for name in cpu:
        med = statistics.median(cpu[name])
        added = ""
        against = against_of[name]
        if against is not None:
            pairs = list(zip(cpu[name], cpu[against], strict=True))
            points = statistics.median(c - b for c, b in pairs)
            ratio = statistics.median(c / b for c, b in pairs if b > 0)
            added = f"{points:+.2f} points ({100 * (ratio - 1):+.1f} %) to the row above"
        got = f"{statistics.median(rates[name]):.0f}" if rates[name] else "-"
        rounds = ", ".join(f"{c:.2f}" for c in cpu[name])
        print(f"| {name} | {rounds} | {med:.2f} | {got} | {added} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
