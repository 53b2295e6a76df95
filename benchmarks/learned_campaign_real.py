"""The hidden scoring of issue 22 on real middleware: learn two minutes, then faults.

    .venv/bin/python benchmarks/learned_campaign_real.py --middleware ros2 --learn 120 \\
        --duration 900 --seed 0 [--motion-seed 5] [--json F] [--out DIR]

Starts the real diffdrive robot of the tests (rclpy on ROS 2, Debian's rospy on ROS 1:
wheel encoders, odometry, IMU, command and battery measuring one motion) with the fault
schedule of ``--seed`` (``scripts/robots/diffdrive_faults.py``: stuck, drift, offset, scale
and noise on the nine moving fields, applied by the nodes themselves, plus kill and stall,
which this harness performs with SIGKILL/restart and SIGSTOP/SIGCONT), learns a
configuration with ``blackbox learn``'s own code for ``--learn`` seconds, then runs the
black box with it until ``--duration`` seconds of faults have passed.

Scored engine-level exactly as ``benchmarks/learned_campaign.py`` scores the simulated
robots (:mod:`blackbox.evaluate.engine_score`, the same tally and table): a component is
reported while a diagnosis ranks it in its first candidate. The scored span starts
``SETTLE`` s after the black box's first observation (discovery) and includes the healthy
seconds before the first fault. False alarms per healthy hour: false-positive episodes over
the scored seconds outside every fault window (its end plus the 2 s grace).

Every miss and every false alarm is printed with what the observers said (the relations'
z, CUSUM and excitation are in their messages); ``--out`` keeps the learned files, the
ground truth, the diagnoses and the observations around each fault.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from blackbox.app import RunOptions
from blackbox.evaluate.engine_score import diagnosis_observations
from blackbox.evaluate.metrics import DEFAULT_GRACE, RunScore, score_run
from blackbox.learn import learn_from, render_config, render_model
from blackbox.model import Diagnosis, Observation
from blackbox.observe.build import load_config
from blackbox.observe.gaps import unmeasured
from blackbox.sinks import SinkBase
from blackbox.sources import open_source
from blackbox.sources.sim import GroundTruth

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from conftest import black_box_running  # noqa: E402
from diffdrive_support import (  # noqa: E402
    SCRIPTS,
    load_script,
    ros1_diffdrive,
    ros2_diffdrive_publishing,
)
from learned_campaign import KindTally, Row, fmt, print_table, tally  # noqa: E402

faults_model = load_script(SCRIPTS / "robots" / "diffdrive_faults.py", "diffdrive_faults")

LEAD = 5.0
"""Seconds into the robot's motion script at which learning starts (as in the tests)."""
READY = 30.0
"""Seconds the robot may take to start before learning; the fault schedule starts after
this, the learning and the black box's settling, so learning never sees a fault."""
SETTLE = 15.0
"""Seconds after the black box's first observation that are not scored: DDS discovery,
the first graph snapshot, the learned filters' first windows."""
LATE = 1.0
"""A kill or stall this harness could begin only within this many seconds of its scheduled
end (its thread starved: seen at load average 49) is not injected and not scored."""
TAIL = 5.0
"""No fault starts in the last seconds of the run (the simulated campaign's rule)."""


@dataclass(frozen=True, slots=True)
class Plan:
    """The run's timing on the robot's motion clock, fixed before the robot starts."""

    epoch: float
    fault_start: float
    duration: float
    faults: tuple[Any, ...]

    def wall(self, motion_time: float) -> float:
        return self.epoch + motion_time


class Keep(SinkBase):
    """Diagnoses, every faulty observation, and the value observers' verdicts inside a fault
    window (known in advance): what the misses and false alarms are explained from."""

    def __init__(self, windows: Sequence[tuple[float, float]]) -> None:
        self.lock = threading.Lock()
        self.windows = sorted(windows)
        self.observations: list[Observation] = []
        self.diagnoses: list[Diagnosis] = []
        self.first: float | None = None

    def _inside(self, t: float) -> bool:
        return any(a <= t <= b for a, b in self.windows)

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self.lock:
            if self.first is None and observations:
                self.first = now
            self.observations.extend(o for o in observations
                                     if o.faulty or self._inside(o.time))

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self.lock:
            self.diagnoses.append(diagnosis)


class ProcessFaults:
    """Performs the schedule's kill and stall faults on the robot's node processes at their
    wall-clock times and logs what it did as ground truth (its own clock, not the plan's)."""

    def __init__(self, robot: Any, plan: Plan, group: bool) -> None:
        self.robot = robot
        self.plan = plan
        self.group = group  # ROS 1 nodes run in sessions of their own
        self.truth: list[GroundTruth] = []
        self.skipped: list[Any] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="process-faults", daemon=True)

    def _signal(self, node: str, sig: int) -> None:
        proc = self.robot.nodes.get(node)
        if proc is None or proc.poll() is not None:
            return
        try:
            if self.group:
                os.killpg(proc.pid, sig)
            else:
                os.kill(proc.pid, sig)
        except OSError:
            pass

    def _wait_until(self, wall: float) -> bool:
        return not self.stop.wait(max(0.0, wall - time.time()))

    def _run(self) -> None:
        actions = []
        for f in self.plan.faults:
            if f.kind in ("kill", "stall"):
                actions.append((self.plan.wall(f.start), "begin", f))
                actions.append((self.plan.wall(f.end), "end", f))
        began: dict[int, float] = {}
        for wall, what, f in sorted(actions, key=lambda a: a[0]):
            if not self._wait_until(wall):
                return
            node = f.node
            if what == "begin":
                if time.time() > self.plan.wall(f.end) - LATE:
                    self.skipped.append(f)  # this thread ran too late: not injected
                    continue
                began[id(f)] = time.time()
                self._signal(node, signal.SIGKILL if f.kind == "kill" else signal.SIGSTOP)
                continue
            if id(f) not in began:
                continue
            if f.kind == "kill":
                proc = self.robot.nodes.get(node)
                if proc is not None:
                    proc.wait(timeout=10)
                self.robot.start_node(node)
            else:
                self._signal(node, signal.SIGCONT)
            self.truth.append(GroundTruth(began[id(f)], time.time(), f.kind, f.component,
                                          node, {}))

    def __enter__(self) -> ProcessFaults:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(timeout=15)
        for node in list(self.robot.nodes):  # nothing stays stopped for the shutdown
            self._signal(node, signal.SIGCONT)


@contextmanager
def robot_running(middleware: str, motion_seed: int, plan: Plan, fault_seed: int,
                  logs: Path, transports: str | None) -> Iterator[tuple[str, Any]]:
    """The diffdrive robot with the fault schedule, started; yields (source spec, robot)."""
    faults = (fault_seed, plan.fault_start, plan.duration - TAIL)
    if middleware == "ros1":
        robot1 = ros1_diffdrive.DiffdriveRobot1(ros1_diffdrive.free_port(), log_dir=logs,
                                                seed=motion_seed, epoch=plan.epoch,
                                                faults=faults)
        try:
            robot1.start()
            yield f"ros1://127.0.0.1:{robot1.port}", robot1
        finally:
            robot1.stop()
        return
    from isolation import fresh_domain

    domain = fresh_domain()
    with ExitStack() as stack:
        try:
            robot2 = stack.enter_context(ros2_diffdrive_publishing(
                domain, seed=motion_seed, log_dir=logs, epoch=plan.epoch, faults=faults,
                transports=transports, within=READY))
        except AssertionError as exc:  # the robot's start, not the caller's code
            raise SystemExit(str(exc)) from None
        yield f"ros2:{domain}", robot2


def value_truth(plan: Plan) -> list[GroundTruth]:
    """The value faults as the nodes apply them: at their scheduled motion times."""
    return [GroundTruth(plan.wall(f.start), plan.wall(f.end), f.kind, f.component, f.node,
                        dict(f.params), f.field)
            for f in plan.faults if f.kind in faults_model.VALUE_KINDS]


def healthy_seconds(truth: Sequence[GroundTruth], start: float, end: float) -> float:
    """Scored seconds outside every fault window (fault start to end plus the grace)."""
    spans = sorted((max(start, g.start), min(end, (g.end or end) + DEFAULT_GRACE))
                   for g in truth)
    covered, reach = 0.0, start
    for a, b in spans:
        a = max(a, reach)
        if b > a:
            covered += b - a
            reach = b
    return (end - start) - covered


def said(observations: Sequence[Observation], limit: int = 4) -> str:
    out = [f"{o.observer} {o.resource.label()} {o.code.name} {o.message}"
           for o in observations[:limit]]
    return "; ".join(out) + (f" (+{len(observations) - limit})" if len(observations) > limit
                             else "")


def explain_misses(score: RunScore, keep: Keep, publishers: dict[str, str], t0: float
                   ) -> list[dict[str, Any]]:
    """Each fault not reported, or reported but not first-ranked, with the value observers'
    verdicts on its topic during its window and the first candidates of the diagnoses."""
    out = []
    for o in score.outcomes:
        if o.detected and o.isolated:
            continue
        g = o.fault
        topic = g.component if g.component in publishers else None
        end = (g.end or score.end) + DEFAULT_GRACE
        mine = [x for x in keep.observations if g.start <= x.time <= end
                and not unmeasured(x)
                and (topic in (x.resource.topic, x.resource.topic_b)
                     or g.node in (x.resource.node,) or g.node in x.resource.publishers)]
        faulty = [x for x in mine if x.faulty]
        relations = [x for x in mine if x.observer == "relation"]
        last_rel: dict[Any, Observation] = {}
        for x in relations:
            last_rel[x.key()] = x
        named = sorted({", ".join(sorted(d.candidates[0])) for d in keep.diagnoses
                        if g.start <= d.time <= end and d.candidates})
        out.append({
            "fault": f"{g.kind} {g.component}{'.' + g.field if g.field else ''} "
                     f"{dict(g.params)} at {g.start - t0:.1f}-{(g.end or score.end) - t0:.1f} s",
            "detected": o.detected, "first_ranked": bool(o.isolated),
            "in_candidates": bool(o.in_candidates),
            "faulty": said(faulty), "relations_last": said(list(last_rel.values()), 6),
            "first_candidates": named[:6]})
    return out


def explain_false_alarms(score: RunScore, keep: Keep, t0: float) -> list[dict[str, Any]]:
    """Each false-positive episode with the failed observations of the diagnosis that
    started it."""
    out = []
    for e in score.false_positives:
        first = next((d for d in keep.diagnoses if d.time >= e.start - 1e-3 and d.candidates),
                     None)
        out.append({"at": round(e.start - t0, 2), "for_s": round(e.end - e.start, 2),
                    "reported": e.key[1].label(),
                    "failed": said(list(first.failed) if first else [], 6),
                    "explanation": first.explanation if first else ""})
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--middleware", choices=["ros1", "ros2"], default="ros2")
    p.add_argument("--learn", type=float, default=120.0, help="seconds of learning (120)")
    p.add_argument("--duration", type=float, default=900.0, help="seconds of faults (900)")
    p.add_argument("--seed", type=int, default=0, help="the fault schedule's seed")
    p.add_argument("--motion-seed", type=int, default=5, help="the robot's motion script")
    p.add_argument("--shared-memory", action="store_true",
                   help="ROS 2: let the robot's Fast DDS nodes use shared memory (default: "
                        "UDPv4 only; a killed node then froze others)")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--out", type=Path, default=None, help="keep files of the run here")
    args = p.parse_args(argv)
    if args.learn <= 0 or args.duration <= TAIL:
        p.error(f"--learn must be > 0 and --duration > {TAIL:g}")
    out = args.out or Path(tempfile.mkdtemp(prefix="learned-campaign-real-"))
    out.mkdir(parents=True, exist_ok=True)
    fault_start = LEAD + READY + args.learn + SETTLE
    epoch = time.time() - LEAD
    plan = Plan(epoch, fault_start, args.duration,
                tuple(faults_model.schedule(args.seed, fault_start, args.duration - TAIL)))
    load_start = os.getloadavg()[0]
    print(f"{args.middleware}: seed {args.seed}, {len(plan.faults)} faults in "
          f"{args.duration:g} s after {args.learn:g} s of learning (motion seed "
          f"{args.motion_seed}); load average at start {load_start:.2f}", flush=True)
    windows = [(plan.wall(f.start), plan.wall(f.end) + DEFAULT_GRACE + 1.0)
               for f in plan.faults]
    keep = Keep(windows)
    transports = None if args.shared_memory else "UDPv4"
    with robot_running(args.middleware, args.motion_seed, plan, args.seed, out / "logs",
                       transports) as (source, robot):
        ready = time.time() - epoch
        if ready + args.learn > fault_start - SETTLE:
            raise SystemExit(f"the robot took {ready - LEAD:.0f} s to start (> {READY:g} s): "
                             "learning would see faults")
        learned = learn_from(lambda: open_source(source), args.learn)
        config = out / "robot.yaml"
        config.write_text(render_config(learned, "robot", "robot.model.yaml", "bench"),
                          encoding="utf-8")
        (out / "robot.model.yaml").write_text(render_model(learned, "bench"),
                                              encoding="utf-8")
        kinds: dict[str, int] = {}
        for e in load_config(config).observers:
            kinds[e["type"].str()] = kinds.get(e["type"].str(), 0) + 1
        print(f"learned in {args.learn:g} s: {kinds}", flush=True)
        options = RunOptions(config=config, source=source, live=False, extra_sinks=[keep])
        end = plan.wall(fault_start + args.duration)
        with black_box_running(options), ProcessFaults(robot, plan,
                                                        args.middleware == "ros1") as process:
            while (left := end - time.time()) > 0:
                time.sleep(min(60.0, left))
                with keep.lock:
                    print(f"{time.time() - plan.wall(fault_start):6.0f} s of faults: "
                          f"{len(keep.diagnoses)} diagnoses", flush=True)
        process_truth = process.truth
        if process.skipped:
            print(f"not injected (the harness ran late): {len(process.skipped)} process "
                  "faults", flush=True)
    load_end = os.getloadavg()[0]
    with keep.lock:
        if keep.first is None:
            raise SystemExit("the black box made no observation")
        start = keep.first + SETTLE
        diagnoses = [d for d in keep.diagnoses if start <= d.time <= end]
    truth = sorted(value_truth(plan) + process_truth, key=lambda g: g.start)
    publishers = dict(faults_model.TOPICS)
    verdicts = diagnosis_observations(diagnoses, publishers, end)
    score = score_run(truth, verdicts, publishers, start=start, end=end, grace=DEFAULT_GRACE,
                      diagnoses=diagnoses)
    row = Row(f"learned ({args.learn:g} s), {args.middleware}, seed {args.seed}")
    tally(row, score, truth, {key: std for key, (std, _) in faults_model.FIELDS.items()})
    healthy = healthy_seconds(truth, start, end)
    row.healthy_alarms = len(score.false_positives)
    per_hour = len(score.false_positives) * 3600.0 / healthy if healthy > 0 else None
    t0 = plan.wall(fault_start)
    misses = explain_misses(score, keep, publishers, t0)
    alarms = explain_false_alarms(score, keep, t0)
    print(f"\n{args.middleware}: scored {end - start:.0f} s ({healthy:.0f} s outside fault "
          f"windows), load average at the end {load_end:.2f}\n")
    print_table([row], healthy)
    print(f"\nfalse-alarm episodes per healthy hour: {fmt(per_hour, 1)} "
          f"({len(score.false_positives)} in {healthy:.0f} s)")
    print("\nnot reported or not first-ranked (times from the first fault slot):")
    for m in misses:
        print(f"- {m['fault']}: detected {m['detected']}, first-ranked {m['first_ranked']}, "
              f"in candidates {m['in_candidates']}\n    faulty: {m['faulty'] or '-'}\n"
              f"    relations (last): {m['relations_last'] or '-'}\n"
              f"    first candidates: {m['first_candidates']}")
    print("\nfalse alarms:")
    for a in alarms:
        print(f"- {a['at']} s for {a['for_s']} s, reported {a['reported']}: {a['failed']}")
    (out / "truth.jsonl").write_text("".join(json.dumps(g.to_dict()) + "\n" for g in truth))
    (out / "diagnoses.jsonl").write_text("".join(json.dumps(d.to_dict()) + "\n"
                                                 for d in diagnoses))
    with (out / "observations.jsonl").open("w", encoding="utf-8") as f:
        for o in keep.observations:
            f.write(json.dumps(o.to_dict()) + "\n")
    o_all = row.overall
    result = {"middleware": args.middleware, "seed": args.seed, "motion_seed": args.motion_seed,
              "learn_s": args.learn, "duration_s": args.duration, "scored_s": end - start,
              "healthy_s": healthy, "load_start": load_start, "load_end": load_end,
              "learned": kinds, "faults": o_all.faults,
              "not_injected": len(process.skipped), "transports": transports, "tp": o_all.detected,
              "fp": o_all.false_alarms, "precision": o_all.precision, "recall": o_all.recall,
              "f1": o_all.f1,
              "first_ranked": o_all.first_ranked / o_all.faults if o_all.faults else None,
              "in_candidates": o_all.in_candidates / o_all.faults if o_all.faults else None,
              "false_alarms_per_healthy_hour": per_hour,
              "per_kind": {k: {"faults": t.faults, "tp": t.detected, "fp": t.false_alarms,
                               "first_ranked": t.first_ranked,
                               "in_candidates": t.in_candidates}
                           for k, t in row.kinds.items()},
              "drift_past_three_std": [
                  {"found_after_s": p if p < float("inf") else None, "lasted_after_s": lasted}
                  for p, lasted in row.kinds.get("drift", KindTally()).past_three_std],
              "misses": misses, "false_alarms": alarms, "out": str(out)}
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2))
    print(f"\nfiles in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
