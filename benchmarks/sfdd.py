"""SFDD: cost of one window judgement, and the engines compared on seeded campaigns.

    .venv/bin/python benchmarks/sfdd.py window [--repeat 200]
    .venv/bin/python benchmarks/sfdd.py engines [--runs 5] [--duration 300] [--grace 2]

``window`` prints microseconds per window (median of ``--repeat`` judgements) for n signals
and a window of m = 100 samples, all pairs (O(m n^2)) next to two reference signals
(O(m n k)). ``engines`` runs the same seeded campaign on ``sim:diffdrive`` for CBD, SFDD, the
hybrid and SFDD's variants (the paper-only ``strict`` mode, Biswas's ``signed``, ``change``
and reference signals, a stricter ``sigmas: 6``) and prints one markdown row per engine:
the engine's diagnoses scored as detections (docs/evaluation.md), isolation per fault kind
and the engine's CPU time.
"""

from __future__ import annotations

import argparse
import platform
import re
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from blackbox.diagnose.sfdd import SfddDetector, SfddSettings
from blackbox.evaluate import CampaignSettings, isolation_by_kind, percentile, run_campaign

CONFIG = Path(__file__).parents[1] / "src" / "blackbox" / "configs" / "diffdrive.yaml"
KINDS = ("stuck", "drift", "offset", "scale", "kill", "stall")
VARIANTS: tuple[tuple[str, str, str], ...] = (
    ("cbd", "cbd", ""),
    ("sfdd", "sfdd", ""),
    ("hybrid", "hybrid", ""),
    ("sfdd strict (thesis 4.2 only)", "sfdd", "strict: true"),
    ("sfdd signed (Biswas)", "sfdd", "signed: true"),
    ("sfdd change (Biswas)", "sfdd", "change: true"),
    ("sfdd 2 references (Biswas)", "sfdd",
     "references: [{topic: /cmd_vel, field: linear.x}, {topic: /cmd_yaw, field: data}]"),
    ("sfdd sigmas 6", "sfdd", "sigmas: 6.0"),
    ("hybrid sigmas 6", "hybrid", "sigmas: 6.0"),
    ("sfdd persistence 3", "sfdd", "persistence: 3"),
    ("sfdd sigmas 6, persistence 3", "sfdd", "sigmas: 6.0\npersistence: 3"),
    ("hybrid sigmas 6, persistence 3", "hybrid", "sigmas: 6.0\npersistence: 3"),
    ("hybrid verify", "hybrid", "hybrid: verify"),
)


def window(n: int, m: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(m) * 0.1
    latents = [np.sin(2 * np.pi * t / p) for p in (23.0, 17.0, 11.0)]
    cols = [latents[i % 3] * (1 + 0.1 * i) for i in range(n)]
    return np.stack(cols, axis=1) + rng.normal(0, 0.02, (m, n))


def median_us(detector: SfddDetector, h: np.ndarray, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        detector.judge(h)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e6


def variant_config(extra: str, folder: Path) -> Path:
    """The shipped configuration with ``extra`` lines in its ``diagnosis.sfdd`` section
    (``hybrid:`` in ``diagnosis``)."""
    text = CONFIG.read_text(encoding="utf-8")
    for line in extra.splitlines():
        if line.startswith("hybrid:"):
            text = text.replace("\n  engine: cbd\n", f"\n  engine: cbd\n  {line}\n", 1)
        else:
            text = re.sub(r"(\n    window: 100\n)", rf"\1    {line}\n", text, count=1)
    path = folder / f"variant{abs(hash(extra))}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def engines(runs: int, duration: float, grace: float) -> None:
    print(f"{runs} runs x {duration:g} s on sim:diffdrive, seeds 0..{runs - 1}, kinds "
          f"{','.join(KINDS)}, grace {grace:g} s")
    head = ("| engine | TP | FP | FN | precision | recall | F1 | delay p50 | top-1 | "
            + " | ".join(KINDS) + " | CPU s |")
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    with tempfile.TemporaryDirectory() as tmp:
        for label, engine, extra in VARIANTS:
            settings = CampaignSettings(config=variant_config(extra, Path(tmp)),
                                        source="sim:diffdrive", runs=runs, duration=duration,
                                        kinds=KINDS, grace=grace, engine=engine)
            result = run_campaign(settings)
            totals = result.engine_totals()
            assert totals is not None
            c, iso, delays, cpu = totals
            per_kind = {k.kind: f"{k.isolated}/{k.faults}"
                        for k in isolation_by_kind(result.outcomes)}
            p50 = percentile(delays, 50)

            def num(x: float | None) -> str:
                return "-" if x is None else f"{x:.3f}"

            print(f"| {label} | {c.tp} | {c.fp} | {c.fn} | {num(c.precision)} | "
                  f"{num(c.recall)} | {num(c.f1)} | "
                  f"{'-' if p50 is None else f'{p50:.2f} s'} | {iso.isolated}/{iso.faults} | "
                  + " | ".join(per_kind.get(k, "-") for k in KINDS) + f" | {cpu:.2f} |",
                  flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("what", choices=("window", "engines"))
    parser.add_argument("--repeat", type=int, default=200)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--grace", type=float, default=2.0)
    args = parser.parse_args()
    if args.what == "engines":
        engines(args.runs, args.duration, args.grace)
        return
    print(f"python {platform.python_version()}, numpy {np.__version__}, "
          f"{platform.processor() or platform.machine()}")
    print(f"{'signals':>8} {'all pairs us':>13} {'2 references us':>16}")
    for n in (6, 12, 24, 48, 96):
        names = [f"s{i}" for i in range(n)]
        h = window(n, 100)
        allpairs = median_us(SfddDetector(names), h, args.repeat)
        refs = median_us(SfddDetector(names, SfddSettings(references=(names[0], names[1]))),
                         h, args.repeat)
        print(f"{n:>8} {allpairs:>13.0f} {refs:>16.0f}")


if __name__ == "__main__":
    main()
