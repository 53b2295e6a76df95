"""Re-diagnosis latency on the generated 1000-node model, two versions side by side.

Runs ``benchmarks/diagnosis.py``'s ``generated_times`` (the ``generated_latency`` table:
1-5 dead nodes, each engine fed all-OK observations first, then the update that turns
180-1,560 observations failed is timed) in child processes, alternating a ``--before``
source tree and this one, and prints median and p90 per fault count over every round, with
the load average. Make the before tree with, for example::

    mkdir -p /tmp/before && git archive <commit> src | tar -x -C /tmp/before

Run: .venv/bin/python benchmarks/rediagnosis.py --before /tmp/before/src [--rounds 4]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHILD = ("import json, sys; sys.path.insert(0, 'benchmarks'); import diagnosis; "
         "print(json.dumps(diagnosis.generated_times({n}, {repeats})))")


def run(src: Path, n: int, repeats: int) -> list[list[float]]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, "-c", CHILD.format(n=n, repeats=repeats)],
                         cwd=ROOT, env=env, check=True, capture_output=True, text=True,
                         timeout=600)
    rows: list[list[float]] = json.loads(out.stdout)
    return rows


def pct(values: list[float], q: float) -> float:
    """Nearest-rank percentile."""
    s = sorted(values)
    return s[min(len(s) - 1, max(0, round(q * len(s) + 0.5) - 1))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="src/ of the version to beat")
    ap.add_argument("--after", type=Path, default=ROOT / "src")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=7, help="engines per fault count")
    ap.add_argument("--nodes", type=int, default=1000)
    args = ap.parse_args()
    versions = {"before": args.before.resolve(), "after": args.after.resolve()}
    rows: dict[str, list[list[float]]] = {v: [] for v in versions}
    loads = [os.getloadavg()[0]]
    for r in range(args.rounds):
        order = list(versions) if r % 2 == 0 else list(reversed(versions))
        for v in order:
            rows[v] += run(versions[v], args.nodes, args.repeats)
        loads.append(os.getloadavg()[0])
    print(f"{args.nodes}-node model, {args.rounds} rounds x {args.repeats} engines per fault "
          f"count and version, alternating; 1-minute load average {min(loads):.2f}-"
          f"{max(loads):.2f}; {os.cpu_count()} CPUs, Python {sys.version.split()[0]}\n")
    print("| faults | failed obs | before median / p90 ms | after median / p90 ms | "
          "after CPU median ms | before / after (median) | top = injected | complete |")
    print("|---|---|---|---|---|---|---|---|")
    for k in range(1, 6):
        b = [x for x in rows["before"] if x[0] == k]
        a = [x for x in rows["after"] if x[0] == k]
        bw, aw = [x[2] * 1e3 for x in b], [x[2] * 1e3 for x in a]
        print(f"| {k} | {statistics.median(x[1] for x in a):.0f} | "
              f"{statistics.median(bw):.2f} / {pct(bw, 0.9):.2f} | "
              f"{statistics.median(aw):.2f} / {pct(aw, 0.9):.2f} | "
              f"{statistics.median(x[3] * 1e3 for x in a):.2f} | "
              f"{statistics.median(bw) / statistics.median(aw):.1f}x | "
              f"{sum(int(x[4]) for x in a)}/{len(a)} vs {sum(int(x[4]) for x in b)}/{len(b)} | "
              f"{sum(int(x[5]) for x in a)}/{len(a)} vs {sum(int(x[5]) for x in b)}/{len(b)} |")


if __name__ == "__main__":
    main()
