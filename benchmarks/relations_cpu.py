"""CPU cost of relation and liveness observers: 10 signals at 100 Hz, side by side.

    .venv/bin/python benchmarks/relations_cpu.py [--seconds 60] [--repeat 3]

Ten topics, one numeric signal each, 100 messages per second each, all measuring one
motion. *Baseline* is what ``blackbox learn`` writes per topic without relations (``hz``,
``timeout`` and a ``fields`` envelope). *With relations* adds one ``liveness`` observer
per topic and a ``relation`` observer for each of the nine neighbouring pairs of topics
(the pairs a learned configuration of ten redundant signals has at most per target,
``MAX_PEERS``, give or take). Built as ``build_observers`` builds them (relations that
share a signal share its grid cell), each message goes to the observers whose interest
names its topic, as the pipeline routes them, and every observer is evaluated once a
second; the figure is process CPU time per second of robot time (median of ``--repeat``).
The acceptance line of issue 22 is that relations add at most 10 % to the black box.
"""

from __future__ import annotations

import argparse
import itertools
import math
import statistics
import time
from types import SimpleNamespace

from blackbox.config.node import ConfigNode
from blackbox.events import MessageArrival
from blackbox.observe.build import build_observer
from blackbox.observe.signals import GridUser, share_cells

TOPICS = [f"/s{i}" for i in range(10)]
RATE = 100.0


def baseline_entries(topics: list[str] = TOPICS, field: str = "x") -> list[str]:
    """Per topic what ``blackbox learn`` writes without relations (``field`` is the signal)."""
    out = []
    for t in topics:
        out.append(f"{{type: hz, topic: {t}, filter: {{type: mean, window_size: 100}}, states: "
                   "[{number: 1, name: nominal, period: {value: {type: in_between, "
                   "lower_bound: 0.009, upper_bound: 0.011}}}]}")
        out.append(f"{{type: timeout, topic: {t}, timeout: 0.5}}")
        out.append(f"{{type: fields, topic: {t}, fields: [{{name: x, field: {field}, filter: "
                   "{type: mean, window_size: 100, deviation: std_deviation}}], states: "
                   "[{number: 1, name: nominal, x: {value: {type: in_between, "
                   "lower_bound: -3, upper_bound: 3}}}]}")
    return out


def relation_entries(topics: list[str] = TOPICS, field: str = "x") -> list[str]:
    """One liveness observer per topic and a relation for each neighbouring pair."""
    out = []
    for t in topics:
        out.append(f"{{type: liveness, topic: {t}, signals: [{{name: x, field: {field}, "
                   "repeats: 5, "
                   "noise: {block: 50, mean: -7.0, std: 0.3, cusum: {k: 0.5, h: 12}}}]}")
    for a, b in itertools.pairwise(topics):
        out.append(
            f"{{type: relation, topic: {a}, topic_b: {b}, relations: [{{name: r, target: "
            f"{{topic: {b}, field: {field}}}, inputs: [{{topic: {a}, field: {field}, lags: "
            "[0.0, 0.05, "
            "0.1], gains: [0.3, 0.4, 0.3]}], block_noise: 0.01, cusum: {k: 0.5, h: 12}, "
            "excitation: 0.02, span: [-5, 5]}]}")
    return out


def measure(entries: list[str], seconds: float) -> float:
    observers = [build_observer(ConfigNode.parse(e)) for e in entries]
    share_cells(o for o in observers if isinstance(o, GridUser))  # as build_observers does
    by_topic: dict[str, list] = {t: [] for t in TOPICS}  # type: ignore[type-arg]
    for o in observers:
        for t in TOPICS:
            if t in o.interest().topics | o.interest().decoded:
                by_topic[t].append(o)
    start = time.process_time()
    n = int(seconds * RATE)
    next_eval = 1.0
    for k in range(n):
        t = k / RATE
        x = math.sin(t) + 0.01 * math.sin(997.0 * t)
        for topic in TOPICS:
            m = MessageArrival(time=t, topic=topic, publisher="/p", size=8,
                               value=SimpleNamespace(x=x))
            for o in by_topic[topic]:
                o.on_message(m)
        if t >= next_eval:
            for o in observers:
                o.evaluate(t)
            next_eval += 1.0
    return (time.process_time() - start) / seconds


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    base = [measure(baseline_entries(), args.seconds) for _ in range(args.repeat)]
    full = [measure(baseline_entries() + relation_entries(), args.seconds)
            for _ in range(args.repeat)]
    b, f = statistics.median(base), statistics.median(full)
    print(f"10 signals x {RATE:g} Hz, {args.seconds:g} s of robot time, median of "
          f"{args.repeat}")
    print("| observers | CPU % of one core | added |")
    print("|---|---|---|")
    print(f"| baseline (hz, timeout, fields per topic) | {100 * b:.2f} | |")
    print(f"| + 10 liveness, 9 relation observers | {100 * f:.2f} | "
          f"{100 * (f - b):.2f} points ({100 * (f / b - 1):.0f} % of the baseline) |")


if __name__ == "__main__":
    main()
