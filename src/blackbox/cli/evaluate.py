"""``blackbox evaluate``: the thesis's fault-injection experiment on the simulated robot."""

from __future__ import annotations

import argparse
import io
import json
import sys
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

from blackbox.app import DEFAULT_CONFIG
from blackbox.evaluate import (
    THESIS_AFTER,
    THESIS_BEFORE,
    CampaignResult,
    CampaignSettings,
    RunResult,
    delay_summary,
    isolation_by_kind,
    parse_kinds,
    percentile,
    run_campaign,
)

EXIT_USAGE = 2


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "evaluate", help="score detection on seeded random fault campaigns (thesis 6.2)",
        description="Run seeded random-fault campaigns on the simulated robot through the real "
                    "pipeline and score the observations (and diagnoses) against the injected "
                    "faults: TP/FP/FN/TN, accuracy, precision, recall, F1 and detection delay, "
                    "next to the thesis's results. Method: docs/evaluation.md.")
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG,
                   help="observer configuration (default: the thesis's ten observers)")
    p.add_argument("--source", default="sim:thesis",
                   help="simulated robot (sim:thesis or sim:TOPOLOGY.yaml), or ros1 / ros2: "
                        "the real demo robot under ROS 1 / ROS 2 with faults injected on "
                        "its processes")
    p.add_argument("--runs", type=int, default=10, help="number of runs (default 10)")
    p.add_argument("--duration", type=float, default=300.0, metavar="S",
                   help="simulated seconds per run (default 300)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first run (run i: seed+i)")
    p.add_argument("--kinds", default="thesis", metavar="thesis|all|none|K1,K2",
                   help="fault kinds to inject: the thesis's five (default), all, none (a "
                        "healthy run: every alarm is false), or a list")
    p.add_argument("--grace", type=float, default=CampaignSettings.grace, metavar="S",
                   help="seconds after a fault's end that still count for it (default 2)")
    p.add_argument("--separation", type=float, default=CampaignSettings.separation,
                   metavar="S", help="quiet seconds between two faults on one node (default 5)")
    p.add_argument("--mean-gap", type=float, default=CampaignSettings.mean_gap, metavar="S",
                   help="mean seconds between fault starts (default 10)")
    p.add_argument("--no-diagnosis", action="store_true", help="score observations only")
    p.add_argument("--engine", choices=("cbd", "sfdd", "hybrid"), default=None,
                   help="diagnosis engine (default: the configuration's diagnosis.engine); "
                        "sfdd and hybrid need diagnosis.sfdd.signals")
    p.add_argument("--json", type=Path, default=None, metavar="OUT",
                   help="write settings, totals, per-kind and per-fault results as JSON")
    p.add_argument("--quiet", action="store_true", help="no per-run progress on stderr")
    p.add_argument("--report", type=Path, default=None, metavar="DIR",
                   help="also run the thesis's filter experiments and write DIR/report.md "
                        "with PNG figures")
    p.add_argument("--fault-free", type=float, default=100.0, metavar="S",
                   help="seconds of the fault-free run of the filter experiments (default 100)")
    p.set_defaults(func=evaluate_command)


def evaluate_command(args: argparse.Namespace) -> int:
    try:
        settings = CampaignSettings(
            config=args.config, source=args.source, runs=args.runs, duration=args.duration,
            seed=args.seed, kinds=parse_kinds(args.kinds), grace=args.grace,
            separation=args.separation, mean_gap=args.mean_gap,
            diagnosis=not args.no_diagnosis, engine=args.engine)
        settings.check()
        progress = None if args.quiet else _progress(settings.runs, sys.stderr)
        tick = None if args.quiet else _tick(settings, sys.stderr)
        result = run_campaign(settings, progress, tick)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    print_report(result, sys.stdout)
    print_engine(result, sys.stdout)
    if args.report is not None:
        from blackbox.evaluate.report import make_report

        text = io.StringIO()
        print_report(result, text)
        say = None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
        path = make_report(settings, result, args.report, text.getvalue(),
                           fault_free=args.fault_free, progress=say)
        print(f"\nwrote {path}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result.to_dict(), indent=1) + "\n", encoding="utf-8")
        print(f"\nwrote {args.json}")
    return 0


def _progress(runs: int, out: TextIO) -> Callable[[RunResult], None]:
    def report(r: RunResult) -> None:
        c = r.score.confusion
        print(f"run {r.index + 1}/{runs} (seed {r.seed}): {len(r.score.outcomes)} faults, "
              f"TP {c.tp} FN {c.fn} FP {c.fp}, {r.wall:.2f} s", file=out, flush=True)
    return report


def _tick(settings: CampaignSettings, out: TextIO) -> Callable[[int, float], None]:
    def report(index: int, seconds: float) -> None:
        print(f"run {index + 1}/{settings.runs}: {seconds:.0f} s of about "
              f"{settings.duration + 5:.0f} s", file=out, flush=True)
    return report


def _num(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _secs(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} s"


def print_report(result: CampaignResult, out: TextIO) -> None:
    """Per-run table, totals next to the thesis, detection per fault kind, false alarms."""
    s = result.settings
    w = out.write
    w(f"{s.runs} runs x {s.duration:g} s on {s.source}, config {s.config}\n"
      f"fault kinds: {', '.join(s.kinds)}; grace {s.grace:g} s, separation "
      f"{s.separation:g} s, mean gap {s.mean_gap:g} s, seeds {s.seed}..{s.seed + s.runs - 1}\n\n")
    diag = result.diagnosis is not None
    head = (f"{'run':>4} {'seed':>5} {'faults':>6} {'TP':>4} {'FN':>4} {'FP':>4} {'TN':>6} "
            f"{'precision':>9} {'recall':>7} {'F1':>6} {'delay p50':>9}")
    w(head + (f" {'isolated':>9}" if diag else "") + "\n")
    for r in result.runs:
        c = r.score.confusion
        line = (f"{r.index + 1:>4} {r.seed:>5} {len(r.score.outcomes):>6} {c.tp:>4} {c.fn:>4} "
                f"{c.fp:>4} {c.tn:>6} {_num(c.precision):>9} {_num(c.recall):>7} "
                f"{_num(c.f1):>6} {_secs(percentile(r.score.delays(), 50)):>9}")
        if diag and r.score.diagnosis is not None:
            line += f" {r.score.diagnosis.isolated:>4}/{r.score.diagnosis.faults:<4}"
        w(line + "\n")
    c = result.confusion
    line = (f"{'all':>4} {'':>5} {len(result.outcomes):>6} {c.tp:>4} {c.fn:>4} {c.fp:>4} "
            f"{c.tn:>6} {_num(c.precision):>9} {_num(c.recall):>7} {_num(c.f1):>6} "
            f"{_secs(percentile(result.delays(), 50)):>9}")
    if diag and result.diagnosis is not None:
        line += f" {result.diagnosis.isolated:>4}/{result.diagnosis.faults:<4}"
    w(line + "\n\n")
    use = result.resources
    if use is not None:
        w(f"black box process during the runs: CPU {use.cpu_percent:.1f} % of one core (mean "
          f"over {use.seconds:.0f} s), RSS mean {use.rss_mean / 1e6:.0f} MB, max "
          f"{use.rss_max / 1e6:.0f} MB\n\n")

    before, after = THESIS_BEFORE, THESIS_AFTER
    rows: list[tuple[str, ...]] = [
        ("faults injected", str(len(result.outcomes)), str(before.injected),
         str(after.injected)),
        ("true positives", str(c.tp), str(before.confusion.tp), str(after.confusion.tp)),
        ("false positives", str(c.fp), str(before.confusion.fp), str(after.confusion.fp)),
        ("false negatives", str(c.fn), str(before.confusion.fn), str(after.confusion.fn)),
        ("true negatives", f"{c.tn} (evaluations)", "not reported", "not reported"),
        ("accuracy, TN = 0 (as thesis)", _pct(c.accuracy_without_tn), _pct(before.accuracy),
         _pct(after.accuracy)),
        ("accuracy, TN per evaluation", _pct(c.accuracy), "-", "-"),
        ("precision", _num(c.precision), f"{before.precision:.2f}", f"{after.precision:.2f}"),
        ("recall", _num(c.recall), f"{before.recall:.2f}", f"{after.recall:.2f}"),
        ("F1", _num(c.f1), f"{before.f1:.2f}", f"{after.f1:.2f}"),
    ]
    _table(out, ("measure", "this campaign", "thesis 1-10", "thesis 11-20 (re-tuned)"), rows)
    w("(thesis columns as printed in Tables 6.7/6.8; its accuracies equal TP/(TP+FP+FN).)\n\n")

    seen_by: dict[str, Counter[str]] = {}
    for o in result.outcomes:
        if o.detected_by is not None:
            seen_by.setdefault(o.fault.kind, Counter())[o.detected_by[0]] += 1
    rows = []
    for k in result.kinds:
        d = delay_summary(k.delays)
        by = ", ".join(f"{name} {n}" for name, n in seen_by.get(k.kind, Counter()).most_common())
        rows.append((k.kind, str(k.faults), str(k.detected), _num(k.recall), _secs(d["p50"]),
                     _secs(d["p90"]), _secs(d["max"]), by or "-"))
    d = delay_summary(result.delays())
    rows.append(("all", str(len(result.outcomes)), str(c.tp), _num(c.recall), _secs(d["p50"]),
                 _secs(d["p90"]), _secs(d["max"]), ""))
    w("detection per fault kind (delay: first related faulty observation - fault start)\n")
    _table(out, ("kind", "faults", "detected", "recall", "delay p50", "p90", "max",
                 "first seen by"), rows)

    missed = Counter(f"{o.fault.kind} on {o.fault.component}"
                     for o in result.outcomes if not o.detected)
    if missed:
        w("\nmissed faults: " + ", ".join(f"{k} x{n}" for k, n in missed.most_common()) + "\n")
    false = Counter(f"{e.key[0]} on {e.key[1].label()}"
                    for r in result.runs for e in r.score.false_positives)
    if false:
        w("false alarms: " + ", ".join(f"{k} x{n}" for k, n in false.most_common()) + "\n")

    if result.diagnosis is not None:
        g = result.diagnosis
        iso = [o.isolation_delay for o in result.outcomes if o.isolation_delay is not None]
        di = delay_summary(iso)
        w(f"\ndiagnosis: {g.isolated}/{g.faults} faults isolated top-1 (first-ranked candidate "
          f"names the faulty node or topic inside the fault's window; rate "
          f"{_num(g.isolation_rate)}), {g.in_candidates}/{g.faults} among the reported "
          f"candidates (soundness; rate {_num(g.candidate_rate)}), "
          f"isolation delay p50 {_secs(di['p50'])}, p90 {_secs(di['p90'])}, max "
          f"{_secs(di['max'])}; {g.correct} diagnoses named an active fault first, "
          f"{g.wrong} did not (precision {_num(g.diagnosis_precision)})\n")
        kinds = isolation_by_kind(result.outcomes)
        rows = [(k.kind, str(k.faults), str(k.isolated), _num(k.isolation_rate),
                 str(k.in_candidates), _num(k.candidate_rate)) for k in kinds]
        rows.append(("all", str(g.faults), str(g.isolated), _num(g.isolation_rate),
                     str(g.in_candidates), _num(g.candidate_rate)))
        w("isolation per fault kind (top-1: first-ranked candidate names the fault; "
          "in candidates: some reported candidate names it)\n")
        _table(out, ("kind", "faults", "top-1", "rate", "in candidates", "rate"), rows)


def print_engine(result: CampaignResult, out: TextIO) -> None:
    """The engine's diagnoses scored as detections (docs/evaluation.md, engines)."""
    totals = result.engine_totals()
    if totals is None:
        return
    c, iso, delays, cpu = totals
    engine = result.settings.engine or "configured"
    out.write(f"\nengine {engine}: diagnoses as detections: TP {c.tp} FP {c.fp} FN {c.fn}, "
              f"precision {_num(c.precision)}, recall {_num(c.recall)}, F1 {_num(c.f1)}, "
              f"delay p50 {_secs(percentile(delays, 50))}, isolated top-1 "
              f"{iso.isolated}/{iso.faults}, engine CPU {cpu:.2f} s over "
              f"{len(result.runs)} runs\n")


def _table(out: TextIO, header: tuple[str, ...], rows: Sequence[tuple[str, ...]]) -> None:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    for r in [header, *rows]:
        cells = [r[0].ljust(widths[0])] + [c.rjust(widths[i + 1]) for i, c in enumerate(r[1:])]
        out.write("  ".join(cells).rstrip() + "\n")
