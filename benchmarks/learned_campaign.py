"""Learned configurations against the shipped engines on correlated-sensor robots (issue 22).

    .venv/bin/python benchmarks/learned_campaign.py [--robot sim:diffdrive|sim:skidsteer]
        [--learn-seed 100] [--learn-duration 600] [--runs 10] [--duration 900]
        [--healthy 3600] [--out DIR] [--only LABEL,...] [--jobs N]

1. Learns a configuration with :func:`blackbox.learn.learn_from` from ``--learn-duration``
   healthy seconds of the robot with seed ``--learn-seed`` (the campaign's seeds are
   0..runs-1, so learning never sees their noise or their schedule of operating modes).
   ``--learn-duration 120`` mirrors the hidden scoring (two minutes of learning).
2. Runs seeds 0..runs-1, each ``--duration`` simulated seconds of random faults: stuck,
   drift, offset, scale and noise on the correlated value fields (those that follow the
   robot's motion) plus kill and stall, the same faults for every configuration.
3. Runs ``--healthy`` fault-free seconds (seed 1000 + learn seed) and counts false-alarm
   episodes of the engine's verdicts.

Configurations: the shipped one (``configs/diffdrive.yaml`` for ``sim:diffdrive``; for a robot
without one, the learned file with the correlated fields named for SFDD, as a user would)
with ``--engine`` cbd, sfdd and hybrid, and the learned configuration with its own engine.

Scores are engine-level (:mod:`blackbox.evaluate.engine_score`, docs/evaluation.md): a
component is reported while a diagnosis ranks it in its first candidate. Per fault kind,
recall, first-ranked isolation, in-candidates isolation and delays are the faults of that
kind; a false-positive episode has no kind, so per kind it is attributed to the kind of the
last fault that ended before it started (its aftermath) and counted in that kind's
precision; false alarms before any fault ended count in the overall row only.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import math
import os
import platform
import shlex
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from blackbox.app import RunOptions, build
from blackbox.evaluate.engine_score import diagnosis_observations
from blackbox.evaluate.metrics import DEFAULT_GRACE, Episode, RunScore, percentile, score_run
from blackbox.learn import learn_from, render_config, render_model
from blackbox.sinks import Collector
from blackbox.sources.sim import GroundTruth, Topology, open_sim, random_campaign
from blackbox.sources.sim.faults import noise_std
from blackbox.sources.sim.messages import scalars_of

SHIPPED = {"sim:diffdrive": Path(__file__).parents[1] / "src" / "blackbox" / "configs"
           / "diffdrive.yaml"}
KINDS = ("stuck", "drift", "offset", "scale", "noise", "kill", "stall")
DRIFT_WITHIN = 5.0
"""Issue 22 item 5: a drift is found within this many seconds of exceeding three noise
standard deviations of its signal."""
ENGINES = ("cbd", "sfdd", "hybrid")


@dataclass(slots=True)
class KindTally:
    """Engine-level counts of one fault kind (or of all, for the overall row)."""

    faults: int = 0
    detected: int = 0
    false_alarms: int = 0
    first_ranked: int = 0
    in_candidates: int = 0
    delays: list[float] = field(default_factory=list)
    past_three_std: list[tuple[float, float]] = field(default_factory=list)
    """Per drift fault whose signal's noise is known: seconds from the drift exceeding
    three noise standard deviations to its detection (``inf`` if never detected), and how
    long the fault lasted from that moment."""

    @property
    def precision(self) -> float | None:
        claimed = self.detected + self.false_alarms
        return self.detected / claimed if claimed else None

    @property
    def recall(self) -> float | None:
        return self.detected / self.faults if self.faults else None

    @property
    def f1(self) -> float | None:
        p, r = self.precision, self.recall
        if p is None or r is None or p + r == 0:
            return None
        return 2 * p * r / (p + r)


@dataclass(slots=True)
class Row:
    label: str
    kinds: dict[str, KindTally] = field(default_factory=dict)
    overall: KindTally = field(default_factory=KindTally)
    healthy_alarms: int = 0


def correlated_fields(topology: Topology) -> list[tuple[str, str]]:
    """(topic, field) of every numeric field that follows the robot's motion."""
    return [(t.name, s.field) for t in topology.topics.values()
            for s in scalars_of(t.value) if s.follows]


def with_sfdd(config: str, signals: Sequence[tuple[str, str]]) -> str:
    """``config`` (a learned file) with the given signals named for SFDD."""
    lines = "".join(f"      - {{topic: {t}, field: '{f}'}}\n" for t, f in signals)
    block = f"diagnosis:\n  sfdd:\n    period: 0.1\n    window: 100\n    signals:\n{lines}"
    return config.replace("diagnosis:\n", block, 1)


def faults_of(topology: Topology, seed: int, duration: float) -> list:
    return random_campaign(topology, duration - 5.0, seed, KINDS, mean_gap=10.0, warmup=5.0,
                           min_separation=5.0, moving_only=True)


def run(config: Path, robot: str, seed: int, duration: float, engine: str | None,
        faults: list) -> tuple[RunScore, list[GroundTruth]]:
    """One run, its engine's verdicts scored as detections."""
    sink = Collector()
    box = build(RunOptions(config=config, source=robot, duration=duration,
                           simulated_clock=True, faults=faults, seed=seed, live=False,
                           engine=engine, extra_sinks=[sink]))
    source = box.pipeline.source
    stats = box.run()
    publishers = source.topic_publishers()  # type: ignore[attr-defined]
    truth: list[GroundTruth] = source.ground_truth  # type: ignore[attr-defined]
    verdicts = diagnosis_observations(sink.diagnoses, publishers, stats.ended)
    return score_run(truth, verdicts, publishers, start=stats.started, end=stats.ended,
                     grace=DEFAULT_GRACE, diagnoses=sink.diagnoses), truth


def aftermath_kind(alarm: Episode, truth: Sequence[GroundTruth], end: float) -> str | None:
    """The kind of the last fault that ended before ``alarm`` started."""
    ended = [f for f in truth if (f.end if f.end is not None else end) <= alarm.start]
    return max(ended, key=lambda f: f.end or end).kind if ended else None


def past_three_std(fault: GroundTruth, delay: float | None, end: float,
                   noise: Mapping[tuple[str, str], float]) -> tuple[float, float] | None:
    """For a drift of known rate on a signal of known noise std: seconds from the drift
    exceeding three noise std (``3 std / |rate|`` after its start) to its detection (``inf``
    if it was never detected) and to the fault's end; ``None`` for any other fault."""
    rate = abs(fault.params.get("rate", 0.0))
    std = noise.get((fault.component, fault.field or ""))
    if fault.kind != "drift" or not rate or not std:
        return None
    crossed = 3.0 * std / rate
    lasted = (fault.end if fault.end is not None else end) - fault.start - crossed
    return (math.inf if delay is None else delay - crossed), lasted


def sim_noise(topology: Topology) -> dict[tuple[str, str], float]:
    """Each simulated field's own measurement noise std; a topic of one field also under
    the empty field (a fault on it names no field)."""
    out: dict[tuple[str, str], float] = {}
    for t in topology.topics.values():
        scalars = scalars_of(t.value)
        for s in scalars:
            out[(t.name, s.field)] = noise_std(s)
        if len(scalars) == 1:
            out[(t.name, "")] = noise_std(scalars[0])
    return out


def tally(row: Row, score: RunScore, truth: Sequence[GroundTruth],
          noise: Mapping[tuple[str, str], float] | None = None) -> None:
    for outcome in score.outcomes:
        past = past_three_std(outcome.fault, outcome.delay, score.end, noise or {})
        for t in (row.overall, row.kinds.setdefault(outcome.fault.kind, KindTally())):
            t.faults += 1
            t.detected += outcome.detected
            t.first_ranked += bool(outcome.isolated)
            t.in_candidates += bool(outcome.in_candidates)
            if outcome.delay is not None:
                t.delays.append(outcome.delay)
            if past is not None:
                t.past_three_std.append(past)
    for alarm in score.false_positives:
        row.overall.false_alarms += 1
        kind = aftermath_kind(alarm, truth, score.end)
        if kind is not None:
            row.kinds.setdefault(kind, KindTally()).false_alarms += 1


@dataclass(frozen=True, slots=True)
class Task:
    """One simulated run of one configuration: the campaign's faults of its seed, or none
    for the healthy run. Runs in a worker process, so it carries names, not objects."""

    row: int
    config: Path
    robot: str
    seed: int
    duration: float
    engine: str | None
    healthy: bool = False


def perform(task: Task) -> tuple[Task, Row]:
    """Run ``task`` and tally it into a fresh :class:`Row` (merged by the caller)."""
    faults = [] if task.healthy else faults_of(open_sim(task.robot).topology, task.seed,
                                               task.duration)
    score, truth = run(task.config, task.robot, task.seed, task.duration, task.engine, faults)
    part = Row("")
    if task.healthy:
        part.healthy_alarms = len(score.false_positives)
    else:
        tally(part, score, truth, sim_noise(open_sim(task.robot).topology))
    return task, part


def merge(into: KindTally, part: KindTally) -> None:
    into.faults += part.faults
    into.detected += part.detected
    into.false_alarms += part.false_alarms
    into.first_ranked += part.first_ranked
    into.in_candidates += part.in_candidates
    into.delays += part.delays
    into.past_three_std += part.past_three_std


def fmt(x: float | None, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def print_table(rows: Sequence[Row], healthy: float) -> None:
    head = ("| configuration | kind | faults | TP | FP | FN | precision | recall | F1 | "
            "first-ranked | in candidates | delay p50 / p90 s | false alarms in healthy "
            f"{healthy:g} s |")
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for row in rows:
        for kind, t in [("all", row.overall), *((k, row.kinds.get(k, KindTally()))
                                                for k in KINDS)]:
            delays = sorted(t.delays)
            alarms = str(row.healthy_alarms) if kind == "all" else ""
            print(f"| {row.label if kind == 'all' else ''} | {kind} | {t.faults} | "
                  f"{t.detected} | {t.false_alarms} | {t.faults - t.detected} | "
                  f"{fmt(t.precision)} | {fmt(t.recall)} | {fmt(t.f1)} | "
                  f"{fmt(t.first_ranked / t.faults if t.faults else None)} | "
                  f"{fmt(t.in_candidates / t.faults if t.faults else None)} | "
                  f"{fmt(percentile(delays, 50), 2)} / {fmt(percentile(delays, 90), 2)} | "
                  f"{alarms} |")
    for row in rows:
        drifts = row.kinds.get("drift", KindTally()).past_three_std
        judged = sorted(p for p, lasted in drifts if lasted >= DRIFT_WITHIN)
        if drifts:
            within = sum(p <= DRIFT_WITHIN for p in judged)
            shorter = [p for p, lasted in drifts if lasted < DRIFT_WITHIN]
            print(f"\n{row.label}: drift found within {DRIFT_WITHIN:g} s of exceeding three "
                  f"noise std: {within} of the {len(judged)} that lasted that long (seconds "
                  f"after: p50 {fmt(percentile(judged, 50), 2)}, p90 "
                  f"{fmt(percentile(judged, 90), 2)}, max "
                  f"{fmt(judged[-1] if judged else None, 2)}; negative: found before); "
                  f"{len(shorter)} ended sooner, {sum(p < math.inf for p in shorter)} of "
                  "them found")


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", default="sim:diffdrive")
    p.add_argument("--learn-seed", type=int, default=100)
    p.add_argument("--learn-duration", type=float, default=600.0)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--duration", type=float, default=900.0)
    p.add_argument("--healthy", type=float, default=3600.0)
    p.add_argument("--out", type=Path, default=None, help="keep the learned files here")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                   help="runs in parallel (default: one per CPU)")
    p.add_argument("--only", default="", help="comma-separated row labels to run (cbd, sfdd, "
                                              "hybrid, learned); default all")
    args = p.parse_args(argv)
    if args.learn_seed in range(args.runs):
        p.error(f"--learn-seed {args.learn_seed} is one of the campaign's seeds 0..{args.runs - 1}")
    print("command: " + shlex.join([sys.executable, *sys.argv]))
    print(f"machine: {platform.node()}, {platform.machine()}, {os.cpu_count()} CPUs, "
          f"python {platform.python_version()}")
    robot = args.robot
    topology = open_sim(robot).topology
    out = args.out or Path(tempfile.mkdtemp(prefix="learned-campaign-"))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    learned = learn_from(lambda: open_sim(robot, seed=args.learn_seed, realtime=False),
                         args.learn_duration)
    name = topology.name
    learned_config = out / f"{name}-learned.yaml"
    text = render_config(learned, f"{name}-robot", f"{name}-learned.model.yaml", "benchmark")
    learned_config.write_text(text, encoding="utf-8")
    (out / f"{name}-learned.model.yaml").write_text(render_model(learned, "benchmark"),
                                                    encoding="utf-8")
    print(f"learned {learned_config} from {args.learn_duration:g} s of {robot} "
          f"(seed {args.learn_seed}) in {time.perf_counter() - t0:.1f} s", flush=True)
    baseline = SHIPPED.get(robot)
    if baseline is None:
        baseline = out / f"{name}-learned-sfdd.yaml"
        baseline.write_text(with_sfdd(text, correlated_fields(topology)), encoding="utf-8")
        base_label = "learned + SFDD signals named"
    else:
        base_label = f"shipped {baseline.name}"
    plans = [*((f"{base_label}, {e}", e, baseline, e) for e in ENGINES),
             (f"learned ({args.learn_duration:g} s, seed {args.learn_seed})", "learned",
              learned_config, None)]
    only = {s.strip() for s in args.only.split(",") if s.strip()}
    campaign = [faults_of(topology, seed, args.duration) for seed in range(args.runs)]
    print(f"{robot}: {args.runs} runs x {args.duration:g} s, seeds 0..{args.runs - 1}, "
          f"{sum(len(c) for c in campaign)} faults of kinds {','.join(KINDS)} (value faults on "
          f"correlated fields); healthy run {args.healthy:g} s (seed {1000 + args.learn_seed})",
          flush=True)
    tasks: list[Task] = []
    rows: list[Row] = []
    for label, key, config, engine in plans:
        if only and key not in only:
            continue
        rows.append(Row(label))
        k = len(rows) - 1
        tasks += [Task(k, config, robot, seed, args.duration, engine)
                  for seed in range(args.runs)]
        if args.healthy > 0:
            tasks.append(Task(k, config, robot, 1000 + args.learn_seed, args.healthy, engine,
                              healthy=True))
    # Longest first, so the healthy hours do not finish last on their own.
    tasks.sort(key=lambda t: -t.duration)
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for task, part in pool.map(perform, tasks):
            row = rows[task.row]
            row.healthy_alarms += part.healthy_alarms
            merge(row.overall, part.overall)
            for kind, t in part.kinds.items():
                merge(row.kinds.setdefault(kind, KindTally()), t)
    print(f"{len(tasks)} runs in {time.perf_counter() - t0:.0f} s wall ({args.jobs} jobs)",
          flush=True)
    print()
    print_table(rows, args.healthy)
    return 0


if __name__ == "__main__":
    sys.exit(main())
