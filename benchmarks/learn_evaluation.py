"""Hand-written thesis observers against a configuration learned by `blackbox learn`.

    .venv/bin/python benchmarks/learn_evaluation.py [--learn-seed 100] [--learn-duration 600]
        [--runs 10] [--duration 300] [--healthy 3600] [--out DIR]

1. Learns a configuration from ``--learn-duration`` healthy seconds of the simulated thesis
   robot with seed ``--learn-seed`` (the campaign uses seeds 0..runs-1, so the learning
   run's noise is not the evaluation's).
2. Runs the thesis campaign (``blackbox evaluate``'s runs, thesis fault kinds) with each
   configuration and scores detection (F1, delay) and isolation: *top-1* (a diagnosis in
   the fault's window ranks first a candidate naming the fault) and *in candidates* (some
   diagnosis in the window lists a candidate naming the fault).
3. Runs ``--healthy`` fault-free seconds (seed 5) with each configuration and counts
   false alarms (episodes of faulty observations) per hour.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from blackbox.app import DEFAULT_CONFIG, RunOptions, build
from blackbox.evaluate.metrics import (
    DEFAULT_GRACE,
    Confusion,
    episodes,
    fault_components,
    percentile,
    score_run,
)
from blackbox.learn import learn_from, render_config, render_model
from blackbox.sinks import Collector
from blackbox.sources.sim import THESIS_FAULT_KINDS, open_sim, random_campaign


def campaign(config: Path, runs: int, duration: float) -> dict[str, float | None]:
    total = Confusion()
    faults = top1 = listed = 0
    delays: list[float] = []
    for seed in range(runs):
        robot = open_sim("sim:thesis", seed=seed, realtime=False)
        injected = random_campaign(robot.topology, duration - 5.0, seed, THESIS_FAULT_KINDS,
                                   mean_gap=10.0, warmup=5.0, min_separation=5.0)
        sink = Collector()
        box = build(RunOptions(config=config, source="sim:thesis", duration=duration,
                               simulated_clock=True, faults=injected, seed=seed, live=False,
                               extra_sinks=[sink]))
        source = box.pipeline.source
        stats = box.run()
        publishers = {t.name: t.publisher for t in robot.topology.topics.values()}
        truth = source.ground_truth  # type: ignore[attr-defined]
        score = score_run(truth, sink.observations, publishers, start=stats.started,
                          end=stats.ended, grace=DEFAULT_GRACE, diagnoses=sink.diagnoses)
        total = total + score.confusion
        delays += score.delays()
        for fault in truth:
            faults += 1
            comps = fault_components(fault, publishers)
            end = (fault.end if fault.end is not None else stats.ended) + DEFAULT_GRACE
            inside = [d for d in sink.diagnoses if fault.start <= d.time <= end and d.candidates]
            if any(comps & set(d.candidates[0]) for d in inside):
                top1 += 1
            if any(comps & set(c) for d in inside for c in d.candidates):
                listed += 1
    return {"faults": faults, "tp": total.tp, "fp": total.fp, "fn": total.fn, "f1": total.f1,
            "top1": top1, "listed": listed, "delay_p50": percentile(sorted(delays), 50),
            "delay_p90": percentile(sorted(delays), 90)}


def healthy(config: Path, duration: float) -> tuple[int, float]:
    sink = Collector()
    build(RunOptions(config=config, source="sim:thesis", duration=duration,
                     simulated_clock=True, seed=5, live=False, extra_sinks=[sink])).run()
    alarms = len(episodes(sink.observations))
    return alarms, alarms / (duration / 3600.0)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--learn-seed", type=int, default=100)
    p.add_argument("--learn-duration", type=float, default=600.0)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--duration", type=float, default=300.0)
    p.add_argument("--healthy", type=float, default=3600.0)
    p.add_argument("--out", type=Path, default=None, help="keep the learned files here")
    args = p.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="learned-"))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    learned = learn_from(lambda: open_sim("sim:thesis", seed=args.learn_seed, realtime=False),
                         args.learn_duration)
    learned_config = out / "thesis-learned.yaml"
    learned_config.write_text(render_config(learned, "thesis-robot",
                                            "thesis-learned.model.yaml", "benchmark"))
    (out / "thesis-learned.model.yaml").write_text(render_model(learned, "benchmark"))
    print(f"learned {learned_config} from {args.learn_duration:g} s (seed {args.learn_seed}) "
          f"in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    rows = []
    for name, config in (("hand-written (configs/thesis.yaml)", DEFAULT_CONFIG),
                         (f"learned ({args.learn_duration:g} s, seed {args.learn_seed})",
                          learned_config)):
        c = campaign(config, args.runs, args.duration)
        alarms, per_hour = healthy(config, args.healthy)
        rows.append((name, c, alarms, per_hour))
    print(f"{args.runs} runs x {args.duration:g} s, thesis fault kinds, seeds 0..{args.runs - 1};"
          f" healthy run {args.healthy:g} s (seed 5)\n")
    print("| configuration | faults | TP | FP | FN | F1 | false alarms / h healthy | "
          "isolation top-1 | faulty in candidates | delay p50 / p90 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, c, alarms, per_hour in rows:
        f1 = "-" if c["f1"] is None else f"{c['f1']:.3f}"
        print(f"| {name} | {c['faults']} | {c['tp']} | {c['fp']} | {c['fn']} | {f1} | "
              f"{per_hour:.1f} ({alarms} in {args.healthy:g} s) | {c['top1']} / {c['faults']} | "
              f"{c['listed']} / {c['faults']} | {c['delay_p50']:.2f} / {c['delay_p90']:.2f} s |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
