"""``blackbox dxc``: score the diagnosis engine on the DX Competition circuits."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from blackbox.config.node import ConfigError
from blackbox.diagnose.dxc import (
    BASELINES,
    REPORTS,
    CircuitDiagnoser,
    load_catalog,
    load_scenario,
)
from blackbox.diagnose.dxc_audit import VERDICTS, audit


def _default_root() -> Path:
    env = os.environ.get("BLACKBOX_DXC")
    if env:
        return Path(env)
    vendored = Path("data/shared/benchmarks/dxc")
    return vendored if vendored.is_dir() else Path("../shared/benchmarks/dxc")


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("dxc", help="diagnose the DX Competition circuit scenarios and "
                                          "print the benchmark score")
    p.add_argument("--model", required=True, help="circuit name, e.g. 74L85 or c432")
    p.add_argument("--limit", type=float, default=1.0, help="seconds per scenario (default 1)")
    p.add_argument("--report", choices=REPORTS, default="best",
                   help="what to report per scenario: the minimum-cardinality diagnosis of "
                        "highest expected score (best, default) or all of them")
    p.add_argument("--scenarios", type=int, default=None, metavar="N",
                   help="only the first N scenarios")
    p.add_argument("--audit", action="store_true",
                   help="instead of scoring, check each published ambiguity group against "
                        "the netlist: is it exactly the minimum-cardinality diagnoses? "
                        "Disagreements come with a witness confirmed by simulation")
    p.add_argument("--root", type=Path, default=None,
                   help="benchmark directory with models/ and scenarios/ "
                        "(default $BLACKBOX_DXC, else data/shared/benchmarks/dxc, "
                        "else ../shared/benchmarks/dxc)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.limit <= 0:
        raise ConfigError("--limit must be > 0", "<command line>")
    args.root = args.root or _default_root()
    model = args.root / "models" / f"{args.model}.xml"
    if not model.is_file():
        known = sorted(p.stem for p in (args.root / "models").glob("*.xml"))
        raise ConfigError(f"no DXC model {args.model!r}; known: {', '.join(known) or 'none'}",
                          str(model))
    files = sorted((args.root / "scenarios" / args.model).glob("*.scn"))[: args.scenarios]
    diagnoser = CircuitDiagnoser(load_catalog(model))
    if args.audit:
        return _audit(diagnoser, files, args.model, args.limit)
    gates = len(diagnoser.circuit.gates)
    print(f"model {args.model}: {gates} gates, {len(files)} scenarios, "
          f"{args.limit:g} s limit per scenario")
    print(f"reporting: {args.report}")
    print(f"{'scenario':<14} {'score':>6} {'reported':>8} {'minimum':>7} {'card':>4} "
          f"{'seconds':>8}  status")
    scores: list[float] = []
    slowest = 0.0
    for f in files:
        r = diagnoser.run(load_scenario(f), args.limit, args.report)
        slowest = max(slowest, r.seconds)
        card = len(r.diagnoses[0]) if r.diagnoses else 0
        status = "complete" if r.complete else "time limit (best so far)"
        if r.score is None:
            status += ", unscored (benchmark has no ground truth)"
            shown = "-"
        else:
            scores.append(r.score)
            shown = f"{r.score:.3f}"
        print(f"{r.scenario:<14} {shown:>6} {len(r.diagnoses):>8} {r.minimum:>7} {card:>4} "
              f"{r.seconds:>8.3f}  {status}")
    if scores:
        print(f"mean score {sum(scores) / len(scores):.3f} over {len(scores)} scored scenarios; "
              f"slowest scenario {slowest:.3f} s")
    baselines = BASELINES.get(args.model)
    if baselines:
        print("published baselines: " + ", ".join(f"{k} {v:.3f}" for k, v in baselines.items()))
    return 0


def _audit(diagnoser: CircuitDiagnoser, files: list[Path], model: str, limit: float) -> int:
    print(f"model {model}: {len(diagnoser.circuit.gates)} gates, {len(files)} scenarios; "
          "published ambiguity group (T) against the minimum-cardinality diagnoses (D), "
          f"{limit:g} s limit per scenario")
    print(f"{'scenario':<14} {'verdict':<19} {'|T|':>5} {'min T':>5} {'|D|':>5} {'min D':>5} "
          f"{'injected':>8}  witness")
    counts = dict.fromkeys(VERDICTS, 0)
    for f in files:
        a = audit(diagnoser, load_scenario(f), limit)
        counts[a.verdict] += 1
        if not a.published:
            injected = "-"
        elif a.injected_in_group:
            injected = "in T"
        elif not a.injected_reproduces:
            injected = "differs"
        else:
            injected = "not in T" if len(a.injected) == a.minimum else "larger"
        witness = "{" + ", ".join(sorted(a.witness)) + "}" if a.witness else ""
        if a.not_minimal:
            witness += f" ({a.not_minimal} of T contain a smaller diagnosis)"
        print(f"{a.scenario:<14} {a.verdict:<19} {a.published:>5} {a.published_minimum:>5} "
              f"{a.found:>5} {a.minimum:>5} {injected:>8}  {witness}")
    print(", ".join(f"{k}: {v}" for k, v in counts.items() if v))
    print("injected: the injected fault set is in T, not in T although minimum, larger than "
          "the minimum (masked faults), or differs from the readings")
    print("a witness explains every sensor reading when its gates give the opposite output "
          "(checked by simulating the netlist); incomplete: T omits it at the same size; "
          "overstated minimum: it is smaller than every member of T")
    return 0
