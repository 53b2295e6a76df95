"""Cost of one SFDD window judgement: all pairs vs Biswas's reference signals.

    .venv/bin/python benchmarks/sfdd.py [--repeat 200]

Prints microseconds per window (median of ``--repeat`` judgements) for n signals and a
window of m = 100 samples, all-pairs (O(m n^2)) next to two reference signals (O(m n k)).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np

from blackbox.diagnose.sfdd import SfddDetector, SfddSettings


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


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=200)
    args = parser.parse_args()
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
