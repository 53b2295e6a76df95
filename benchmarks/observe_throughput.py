"""Message arrivals per second through hz + timeout + scores observers on one core.

100 topics, each observed by an ``hz`` observer (mean filter, window 50, gauss state),
a ``timeout`` observer and a ``scores`` observer (mean filter, window 50) on the ``data``
field. Arrivals are pre-generated (1 kHz per topic) and replayed through the real
pipeline (dispatch, evaluation every simulated second, no sinks), so the figure is the
cost of observation alone. CPU time is process time of this single-threaded process.

Run: .venv/bin/python benchmarks/observe_throughput.py [--topics 100] [--seconds 5]
"""

from __future__ import annotations

import argparse
import platform
import time
from types import SimpleNamespace

from blackbox.config.node import ConfigNode
from blackbox.events import Event, MessageArrival
from blackbox.observe.build import build_observer
from blackbox.pipeline import Pipeline
from blackbox.sources.memory import MemorySource

TARGET = 250_000


def observer_config(topics: int) -> str:
    lines = ["observers:"]
    for i in range(topics):
        t = f"/bench/topic_{i:03d}"
        lines += [
            f"  - {{type: hz, topic: {t}, filter: {{type: mean, window_size: 50}},",
            "     states: [{number: 1, name: ok, period: {value: {type: gauss, mean: 0.001,"
            " std_deviation: 0.0005}}}]}",
            f"  - {{type: timeout, topic: {t}, timeout: 1.0, max_timeouts_in_a_row: 1}}",
            f"  - {{type: scores, topic: {t}, filter: {{type: mean, window_size: 50}},",
            "     states: [{number: 1, name: ok, score: {value: {type: gauss, mean: 15.0,"
            " std_deviation: 0.5}}}]}",
        ]
    return "\n".join(lines) + "\n"


def make_arrivals(topics: int, seconds: float, rate: float) -> list[Event]:
    names = [f"/bench/topic_{i:03d}" for i in range(topics)]
    values = [SimpleNamespace(data=15.0 + 0.1 * ((k % 7) - 3)) for k in range(7)]
    events: list[Event] = []
    steps = int(seconds * rate)
    for step in range(steps):
        t = (step + 1) / rate
        for j, name in enumerate(names):
            events.append(MessageArrival(t + j * 1e-7, name, "/bench_node", 8,
                                         value=values[(step + j) % 7]))
    return events


def run(topics: int, seconds: float, rate: float) -> dict[str, float]:
    import blackbox.observe.observers  # noqa: F401 - registers the observer types

    root = ConfigNode.parse(observer_config(topics), "<benchmark>")
    observers = [build_observer(e) for e in root["observers"].list()]
    events = make_arrivals(topics, seconds, rate)
    pipeline = Pipeline(MemorySource(events), observers)
    pipeline.start()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    t = 0.0
    while t < seconds:
        t += 1.0
        pipeline.step(t)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    faulty = pipeline.stats.faulty_observations
    return {"arrivals": len(events), "cpu_s": cpu, "wall_s": wall,
            "per_s": len(events) / cpu, "observers": len(observers),
            "observations": pipeline.stats.observations, "faulty": faulty}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--topics", type=int, default=100)
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds")
    parser.add_argument("--rate", type=float, default=1000.0, help="Hz per topic")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, Python "
          f"{platform.python_version()}")
    print(f"{args.topics} topics x {args.rate:g} Hz x {args.seconds:g} s, "
          f"3 observers per topic (hz + timeout + scores, mean filters of window 50)")
    best = None
    for i in range(args.repeat):
        r = run(args.topics, args.seconds, args.rate)
        print(f"  run {i + 1}: {r['arrivals']:,} arrivals in {r['cpu_s']:.3f} s CPU -> "
              f"{r['per_s']:,.0f} arrivals/s ({r['observations']:,} observations, "
              f"{r['faulty']} faulty)")
        best = r if best is None or r["per_s"] > best["per_s"] else best
    assert best is not None
    core_fraction = args.topics * 1000.0 / best["per_s"]
    print()
    print(f"{'measure':44} {'black box':>14} {'target':>14} {'ratio':>7}")
    print(f"{'arrivals/s on one core (best of runs)':44} {best['per_s']:>14,.0f} "
          f"{TARGET:>14,} {best['per_s'] / TARGET:>6.2f}x")
    print(f"{'cores for 100 topics at 1 kHz':44} {core_fraction:>14.2f} {0.5:>14.2f} "
          f"{0.5 / core_fraction:>6.2f}x")


if __name__ == "__main__":
    main()
