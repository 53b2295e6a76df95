"""The thesis fault campaign on the thesis robot rebuilt as rclpy nodes (ROS 2, Fast DDS):
real faults on real processes, watched by the black box over ``--source ros2``, scored
like the simulator's campaigns (``blackbox evaluate``).

    .venv/bin/python benchmarks/ros2_campaign.py [--duration 300] [--seed 0] [--runs 1]
        [--config src/blackbox/configs/thesis.yaml] [--mean-gap 10] [--length 5:15]
        [--json out.json]

Per run: the three nodes start on a fresh domain, the black box (built in this process
through ``blackbox.app.build``, default configuration = the thesis's ten observers) starts
once they are in the graph, then faults of the thesis kinds (kill, stall, rate, offset,
scale; ``scripts/ros2_robot/inject.py``) are injected one at a time with random lengths
and exponential gaps, none in the last ``--tail`` seconds. Each run is scored with
``blackbox.evaluate.metrics.score_run`` (grace 2 s) from ``--startup`` seconds after the
black box started (before that it has no graph yet and says so with NOT_AVAILABLE, which
the metrics count as faulty; the first fault comes after ``--warmup``): a fault is
detected when a faulty episode of an observer of its components starts inside it; a
faulty episode on a component that overlaps no fault is a false positive.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts" / "ros2_robot"))
sys.path.insert(1, str(ROOT / "scripts"))  # fault_injection, shared with the ROS 1 robot
from fault_injection import random_fault  # noqa: E402
from inject import KINDS, Injector  # noqa: E402
from robot import NODES, TOPICS, ParameterClient, ThesisRobot2  # noqa: E402

from blackbox.app import DEFAULT_CONFIG, RunOptions, build  # noqa: E402
from blackbox.evaluate.metrics import (  # noqa: E402
    DEFAULT_GRACE,
    Confusion,
    DiagnosisScore,
    RunScore,
    percentile,
    score_run,
)
from blackbox.model import Diagnosis, Observation  # noqa: E402
from blackbox.sinks import SinkBase  # noqa: E402
from blackbox.sources.sim.faults import GroundTruth  # noqa: E402


class Collector(SinkBase):
    def __init__(self) -> None:
        self.observations: list[Observation] = []
        self.diagnoses: list[Diagnosis] = []
        self.lock = threading.Lock()

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self.lock:
            self.observations.extend(observations)

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self.lock:
            self.diagnoses.append(diagnosis)


def one_run(args: argparse.Namespace, index: int, domain: int, work: Path) -> RunScore:
    rng = random.Random(args.seed + index)
    robot = ThesisRobot2(domain, log_dir=work / f"run{index}")
    params = ParameterClient(domain)
    sink = Collector()
    truth: list[GroundTruth] = []
    stop = threading.Event()
    try:
        robot.start()
        for node in NODES:
            if not params.wait_for_node(node, 30):
                raise RuntimeError(f"{node} did not join the graph")
        box = build(RunOptions(config=args.config, source=f"ros2:{domain}", live=False,
                               extra_sinks=[sink]))
        thread = threading.Thread(target=box.run, args=(stop,), daemon=True)
        started = time.time()
        thread.start()
        injector = Injector(robot, params)
        time.sleep(args.warmup)
        last_end: dict[str, float] = {}
        while time.time() < started + args.duration - args.tail - args.length[1]:
            kind, component, fparams = random_fault(rng, args.kinds, NODES, TOPICS)
            node = (NODES.get(component) and component) or TOPICS.get(component, component)
            wait = last_end.get(node, 0.0) + args.separation - time.time()
            if wait > 0:
                time.sleep(wait)
            fault = injector.begin(kind, component, **fparams)
            time.sleep(rng.uniform(*args.length))
            rec = injector.end(fault)
            last_end[fault.node] = rec["end"]
            truth.append(GroundTruth.from_dict(rec))
            print(f"  {rec['start'] - started:7.1f} s {kind:6} {component} {fparams}",
                  file=sys.stderr, flush=True)
            if kind == "kill":
                params.wait_for_node(component, 30)
            time.sleep(min(rng.expovariate(1.0 / args.mean_gap), 3 * args.mean_gap))
        remaining = started + args.duration - time.time()
        if remaining > 0:
            time.sleep(remaining)
        ended = time.time()
    finally:
        stop.set()
        params.close()
        robot.stop()
    time.sleep(0.5)
    with sink.lock:  # the black box's own start-up (no graph yet) is not the robot's fault
        observations = [o for o in sink.observations if o.time >= started + args.startup]
        diagnoses = list(sink.diagnoses)
    return score_run(truth, observations, TOPICS, start=started, end=ended,
                     grace=args.grace, diagnoses=diagnoses)


def _span(text: str) -> tuple[float, float]:
    lo, _, hi = text.partition(":")
    return float(lo), float(hi or lo)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--mean-gap", type=float, default=10.0)
    parser.add_argument("--length", type=_span, default=(5.0, 15.0))
    parser.add_argument("--separation", type=float, default=5.0)
    parser.add_argument("--warmup", type=float, default=10.0)
    parser.add_argument("--tail", type=float, default=5.0)
    parser.add_argument("--startup", type=float, default=5.0,
                        help="seconds of the black box's start-up left out of the score")
    parser.add_argument("--grace", type=float, default=DEFAULT_GRACE)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    args.kinds = [k for k in args.kinds.split(",") if k]
    import tempfile

    total = Confusion(0, 0, 0)
    diag = DiagnosisScore()
    delays: list[float] = []
    per_run = []
    with tempfile.TemporaryDirectory(prefix="ros2-campaign-") as tmp:
        for i in range(args.runs):
            domain = random.Random().randrange(150, 230)
            score = one_run(args, i, domain, Path(tmp))
            total = total + score.confusion
            if score.diagnosis is not None:
                diag = diag + score.diagnosis
            delays += score.delays()
            per_run.append(score.to_dict())
            c = score.confusion
            print(f"run {i} (seed {args.seed + i}, domain {domain}): {len(score.outcomes)} "
                  f"faults, TP {c.tp} FP {c.fp} FN {c.fn}", flush=True)
            for e in score.false_positives:
                print(f"    false positive: {e.key[0]} {e.key[1].label()} "
                      f"{e.start - score.start:.1f}-{e.end - score.start:.1f} s", flush=True)
            for o in score.outcomes:
                if not o.detected:
                    print(f"    missed: {o.fault.kind} {o.fault.component} at "
                          f"{o.fault.start - score.start:.1f} s", flush=True)

    def fmt(x: float | None) -> str:
        return "-" if x is None else f"{x:.3f}"

    print(f"faults {total.tp + total.fn}: TP {total.tp} FP {total.fp} FN {total.fn}; "
          f"precision {fmt(total.precision)} recall {fmt(total.recall)} F1 {fmt(total.f1)}; "
          f"delay p50 {fmt(percentile(delays, 50))} p90 {fmt(percentile(delays, 90))} "
          f"max {fmt(max(delays) if delays else None)} s; isolated {diag.isolated}/"
          f"{diag.faults}")
    if args.json:
        args.json.write_text(json.dumps({"runs": per_run, "confusion": total.to_dict()},
                                        indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
