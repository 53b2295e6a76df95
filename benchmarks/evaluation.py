"""Detection quality on the thesis experiment (section 6.2.1.2), next to the thesis's results.

Ten seeded runs of five simulated minutes with random faults, through the real pipeline
(observers and diagnosis) on the simulated thesis robot, for two set-ups:

- the thesis's ten observers (``configs/thesis.yaml``) with the fault kinds the thesis
  injected (kill, stall, rate, offset, scale);
- the extended configuration (``configs/thesis-extended.yaml``) with all nine fault kinds.

Each set-up runs with faults on one node at least 5 s apart (the default: every fault is a
separate event) and back to back (separation 0: a new fault may start while the previous
one's alarm is still on). Scoring rules: docs/evaluation.md.

Run: .venv/bin/python benchmarks/evaluation.py [--runs 10] [--duration 300] [--seed 0]
"""

from __future__ import annotations

import argparse
import platform
import time

from blackbox.app import DEFAULT_CONFIG
from blackbox.evaluate import (
    KIND_SETS,
    THESIS_AFTER,
    THESIS_BEFORE,
    CampaignResult,
    CampaignSettings,
    delay_summary,
    run_campaign,
)

EXTENDED = DEFAULT_CONFIG.with_name("thesis-extended.yaml")


def fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def delays(values: list[float] | tuple[float, ...]) -> str:
    d = delay_summary(values)
    if not d["count"]:
        return "-"
    return f"{d['p50']:.2f} / {d['p90']:.2f} / {d['max']:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    setups = [
        ("thesis config, thesis kinds", DEFAULT_CONFIG, "thesis"),
        ("extended config, all kinds", EXTENDED, "all"),
    ]
    results: list[tuple[str, float, CampaignResult, float]] = []
    for name, config, kinds in setups:
        for separation in (5.0, 0.0):
            settings = CampaignSettings(config=config, runs=args.runs, duration=args.duration,
                                        seed=args.seed, kinds=KIND_SETS[kinds],
                                        separation=separation)
            started = time.perf_counter()
            result = run_campaign(settings)
            results.append((name, separation, result, time.perf_counter() - started))

    print(f"{args.runs} runs x {args.duration:g} simulated s, seeds {args.seed}.."
          f"{args.seed + args.runs - 1}, grace 2 s; Python {platform.python_version()}\n")
    head = ("setup", "sep", "faults", "TP", "FP", "FN", "TN", "acc TN=0", "acc", "prec",
            "recall", "F1", "delay p50/p90/max s", "isolated", "wall s")
    rows = []
    for name, sep, r, wall in results:
        c = r.confusion
        g = r.diagnosis
        rows.append((name, f"{sep:g}", str(len(r.outcomes)), str(c.tp), str(c.fp), str(c.fn),
                     str(c.tn), fmt(c.accuracy_without_tn), fmt(c.accuracy), fmt(c.precision),
                     fmt(c.recall), fmt(c.f1), delays(r.delays()),
                     "-" if g is None else f"{g.isolated}/{g.faults}", f"{wall:.1f}"))
    for t in (THESIS_BEFORE, THESIS_AFTER):
        c = t.confusion
        rows.append((t.name, "-", str(t.injected), str(c.tp), str(c.fp), str(c.fn), "-",
                     f"{t.accuracy:.3f}", "-", f"{t.precision:.2f}", f"{t.recall:.2f}",
                     f"{t.f1:.2f}", "about 1 s", "-", "-"))
    table(head, rows)

    print("\ndetection delay per fault kind, p50 / p90 / max seconds (recall)")
    for name, sep, r, _ in results:
        print(f"\n{name}, separation {sep:g} s")
        table(("kind", "faults", "detected", "recall", "delay p50/p90/max s"),
              [(k.kind, str(k.faults), str(k.detected), fmt(k.recall), delays(k.delays))
               for k in r.kinds])


def table(head: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    for r in [head, *rows]:
        cells = [r[0].ljust(widths[0])] + [c.rjust(widths[i + 1]) for i, c in enumerate(r[1:])]
        print("  ".join(cells).rstrip())


if __name__ == "__main__":
    main()
