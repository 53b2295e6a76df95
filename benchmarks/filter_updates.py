"""Cost of one ``update`` of each filter, and of ``HzObserver.on_message``.

Best of 5 passes over 100,000 Gaussian samples per case, the cost of the bare loop
subtracted. One core, process as quiet as the machine allows.

Run: .venv/bin/python benchmarks/filter_updates.py
"""

from __future__ import annotations

import platform
import random
import timeit
from collections.abc import Callable

from blackbox.config.node import ConfigNode
from blackbox.events import MessageArrival
from blackbox.observe.base import OBSERVERS, Filter
from blackbox.observe.filters import (
    MIN_MAX,
    EwmaFilter,
    KMeansFilter,
    MeanFilter,
    MedianFilter,
    NoFilter,
)

SAMPLES = 100_000
PASSES = 5

FILTERS: dict[str, Callable[[], Filter]] = {
    "mean, window 50": lambda: MeanFilter(50),
    "mean, window 50, min_max": lambda: MeanFilter(50, MIN_MAX),
    "median, window 50": lambda: MedianFilter(50),
    "median, window 1000": lambda: MedianFilter(1000),
    "kmeans, window 50, k 10": lambda: KMeansFilter(50, 10),
    "ewma, decay 0.05": lambda: EwmaFilter(0.05),
    "ewma, decay 0.05, window 20": lambda: EwmaFilter(0.05, 20),
    "nofilter": lambda: NoFilter(),
}


def per_call_ns(make: Callable[[], Callable[[object], object]], inputs: list) -> float:
    loop = min(timeit.repeat(lambda: [None for _ in inputs], number=1, repeat=PASSES))
    best = float("inf")
    for _ in range(PASSES):
        call = make()
        best = min(best, timeit.timeit(lambda c=call: [c(x) for x in inputs], number=1))
    return 1e9 * (best - loop) / len(inputs)


def hz_observer() -> Callable[[object], object]:
    import blackbox.observe.observers  # noqa: F401 - registers the observer types

    node = ConfigNode.parse("{type: hz, topic: /t, filter: {type: mean, window_size: 50}}",
                            "<benchmark>")
    return OBSERVERS["hz"].build(node).on_message


def main() -> None:
    rng = random.Random(1)
    samples = [rng.gauss(15.0, 0.5) for _ in range(SAMPLES)]
    arrivals = [MessageArrival(i / 1000.0, "/t", "/p", 8) for i in range(SAMPLES)]
    print(f"Python {platform.python_version()}, {SAMPLES:,} samples, best of {PASSES}")
    print(f"{'what':34} {'ns per call':>12}")
    for name, make in FILTERS.items():
        print(f"{'filter ' + name:34} {per_call_ns(lambda m=make: m().update, samples):>12,.0f}")
    print(f"{'HzObserver.on_message (mean 50)':34} {per_call_ns(hz_observer, arrivals):>12,.0f}")


if __name__ == "__main__":
    main()
