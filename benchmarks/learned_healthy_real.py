"""False alarms of a learned configuration on a real, healthy robot, over a long run.

    .venv/bin/python benchmarks/learned_healthy_real.py --middleware ros2 --learn 120 --healthy 3600
    .venv/bin/python benchmarks/learned_healthy_real.py --middleware ros1 --learn 120 --healthy 3600
    .venv/bin/python benchmarks/learned_healthy_real.py --healthy 600 --out /tmp/lh   # keep files

Starts the real diffdrive robot of the tests (rclpy on ROS 2, Debian's rospy on ROS 1:
wheel encoders, odometry, IMU, command and battery measuring one motion), learns a
configuration with ``blackbox learn``'s own code for ``--learn`` seconds, then runs the
black box with it for ``--healthy`` seconds while nothing is injected. Every alarm is a
false one. Printed per observer type: false-alarm *episodes* (a subject going from not
faulty to faulty; ``NOT_AVAILABLE`` and measurement gaps are no verdict), faulty
observations, and the diagnoses that named a candidate (after a 10 s settle), with
the first few episodes in words; ``--json`` writes the same. The load average is printed
at the start and the end (the figures are the machine's under that load).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path

from blackbox.app import RunOptions
from blackbox.learn import learn_from, render_config, render_model
from blackbox.model import Code, Diagnosis, Observation
from blackbox.observe.build import load_config
from blackbox.observe.gaps import unmeasured
from blackbox.sinks import SinkBase
from blackbox.sources import open_source

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from conftest import black_box_running  # noqa: E402
from diffdrive_support import ros1_diffdrive, ros2_diffdrive_publishing  # noqa: E402

LEAD = 5.0
"""Seconds into the robot's motion script at which learning starts (as in the tests)."""
SETTLE = 10.0
"""Seconds after the black box's first observation that are not judged: DDS discovery and
the first graph snapshot (the real campaigns settle 8 s)."""


class Episodes(SinkBase):
    """Counts false-alarm episodes per observer type and keeps the diagnoses that accused."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.faulty: dict[tuple[str, str], bool] = {}
        self.episodes: Counter[str] = Counter()
        self.observations: Counter[str] = Counter()
        self.first: list[str] = []
        self.accusing: list[Diagnosis] = []
        self.start: float | None = None
        self.trace: list[str] = []
        """``time,quantity,value`` of every relation quantity (``--out``), the quantity named
        ``<observer's resource>:<quantity>``."""

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self.lock:
            if self.start is None:
                self.start = now
            for o in observations:
                if o.observer == "relation":
                    where = o.resource.label().replace(",", ";")
                    self.trace.extend(f"{now - self.start:.2f},{where}:{k},{v:.5g}"
                                      for k, v in o.values.items())
            if now - self.start < SETTLE:
                return
            for o in observations:
                if o.code == Code.NOT_AVAILABLE or unmeasured(o):
                    continue  # no verdict: neither an alarm nor the end of one
                key = (o.observer, o.resource.label())
                if o.faulty:
                    self.observations[o.observer] += 1
                    if not self.faulty.get(key, False):
                        self.episodes[o.observer] += 1
                        if len(self.first) < 12:
                            self.first.append(f"{now - self.start:7.1f} s {o.observer} "
                                              f"{o.resource.label()}: {o.message}")
                self.faulty[key] = o.faulty

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        if diagnosis.candidates and self.start is not None \
                and diagnosis.time - self.start >= SETTLE:
            with self.lock:
                self.accusing.append(diagnosis)


@contextmanager
def robot_running(middleware: str, seed: int, logs: Path) -> Iterator[str]:
    """The diffdrive robot, started; yields the black box's source spec."""
    epoch = time.time() - LEAD
    if middleware == "ros1":
        robot1 = ros1_diffdrive.DiffdriveRobot1(ros1_diffdrive.free_port(), log_dir=logs,
                                                seed=seed, epoch=epoch)
        try:
            robot1.start()
            yield f"ros1://127.0.0.1:{robot1.port}"
        finally:
            robot1.stop()
        return
    domain = 150 + os.getpid() % 50
    with ExitStack() as stack:
        try:
            stack.enter_context(ros2_diffdrive_publishing(domain, seed=seed, log_dir=logs,
                                                          epoch=epoch, within=60.0))
        except AssertionError as silent:  # the robot did not come up: one line, no traceback
            raise SystemExit(str(silent)) from None
        yield f"ros2:{domain}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--middleware", choices=["ros1", "ros2"], default="ros2")
    p.add_argument("--learn", type=float, default=120.0, help="seconds of learning (120)")
    p.add_argument("--healthy", type=float, default=3600.0, help="healthy seconds (3600)")
    p.add_argument("--seed", type=int, default=5, help="the robot's motion script")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--out", type=Path, default=None,
                   help="keep the learned files and relations.csv (time, resource:quantity, value) "
                   "here")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="learned-healthy-") as tmp_name:
        tmp = Path(tmp_name)
        print(f"load average at start: {os.getloadavg()[0]:.2f}", flush=True)
        with robot_running(args.middleware, args.seed, tmp / "logs") as source:
            learned = learn_from(lambda: open_source(source), args.learn)
            config = tmp / "robot.yaml"
            config.write_text(render_config(learned, "robot", "robot.model.yaml", "bench"),
                              encoding="utf-8")
            (tmp / "robot.model.yaml").write_text(render_model(learned, "bench"),
                                                  encoding="utf-8")
            kept = {name: (tmp / name).read_text(encoding="utf-8")
                    for name in ("robot.yaml", "robot.model.yaml")}
            kinds = Counter(e["type"].str() for e in load_config(config).observers)
            print(f"learned in {args.learn:g} s: {dict(kinds)}", flush=True)
            sink = Episodes()
            options = RunOptions(config=config, source=source, live=False, extra_sinks=[sink])
            began = time.monotonic()
            with black_box_running(options):
                while time.monotonic() - began < args.healthy:
                    time.sleep(min(60.0, args.healthy - (time.monotonic() - began)))
                    with sink.lock:
                        print(f"{time.monotonic() - began:6.0f} s: false-alarm episodes "
                              f"{sum(sink.episodes.values())}, accusing diagnoses "
                              f"{len(sink.accusing)}", flush=True)
        load_end = os.getloadavg()[0]
    with sink.lock:
        result = {"middleware": args.middleware, "learn_s": args.learn,
                  "healthy_s": args.healthy, "episodes": dict(sink.episodes),
                  "faulty_observations": dict(sink.observations),
                  "accusing_diagnoses": len(sink.accusing), "first": sink.first,
                  "per_hour": sum(sink.episodes.values()) * 3600.0 / args.healthy,
                  "load_end": load_end}
    print(f"\n{args.middleware}: learned {args.learn:g} s, healthy {args.healthy:g} s, "
          f"load average at the end {load_end:.2f}")
    print(f"{'observer':<12} {'episodes':>8} {'faulty observations':>20}")
    for kind in sorted(set(sink.episodes) | {"relation"}):
        print(f"{kind:<12} {sink.episodes[kind]:>8} {sink.observations[kind]:>20}")
    print(f"false-alarm episodes per hour: {result['per_hour']:.2f}; diagnoses naming a "
          f"candidate: {result['accusing_diagnoses']}")
    for line in sink.first:
        print("  " + line)
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        for name in ("robot.yaml", "robot.model.yaml"):
            (args.out / name).write_text(kept[name], encoding="utf-8")
        (args.out / "relations.csv").write_text(
            "time,quantity,value\n" + "\n".join(sink.trace) + "\n", encoding="utf-8")
        print(f"learned files and the relation trace in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
