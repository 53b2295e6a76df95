"""The thesis's filter experiments (section 6.2.1.1, Figs. 6.10 and 6.11), repeated.

The thesis ran its robot fault-free for 100 s per filter type and window size (2-100
samples) and counted false positives (Fig. 6.10), then measured the detection delay of the
mean filter over the window size (Fig. 6.11). Here every filtered observer of a
configuration (``hz``, ``scores``, ...) gets the filter under test, and:

- **false positives**: alarms (episodes, docs/evaluation.md) in a fault-free run;
- **detection delay** and **false alarms under faults**: the seeded fault campaign scored
  with the documented episode definition (median delay of the detected faults).

On the simulator every point is a fresh run on the simulated clock. On real middleware the
robot's events are recorded once (a fault-free run and the campaign runs) and replayed
through every filter setting, so every point sees the very same real messages.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from blackbox.app import RunOptions, build
from blackbox.evaluate.metrics import RunScore, episodes, percentile, score_run
from blackbox.evaluate.real_campaign import RealRun
from blackbox.model import Observation
from blackbox.observe.build import build_observers, load_config_text
from blackbox.pipeline import Pipeline
from blackbox.sinks import Collector
from blackbox.sources.base import RandomFaults
from blackbox.sources.memory import MemorySource

FILTER_TYPES: tuple[str, ...] = ("mean", "median", "kmeans", "ewma")
WINDOW_SIZES: tuple[int, ...] = (2, 5, 10, 20, 30, 50, 75, 100)
FILTERED_KINDS: tuple[str, ...] = ("rate", "offset", "scale", "stuck", "drift")
"""Fault kinds seen through a filter (rates, values); kills and stalls are seen unfiltered
by ``activated`` and ``timeout``, so they do not show a filter's delay."""


def filter_spec(kind: str, window: int) -> dict[str, Any]:
    """The filter under test. k-means uses k = 3 clusters (fewer for tiny windows); EWMA a
    decay rate of 2 / (window + 1), the usual span equivalence, so its memory grows with
    the window like the others' (the thesis does not give the decay it used per window)."""
    if kind in ("mean", "median"):
        return {"type": kind, "window_size": window, "deviation": "std_deviation"}
    if kind == "kmeans":
        return {"type": "kmeans", "window_size": window, "k_size": min(3, window),
                "deviation": "std_deviation"}
    if kind == "ewma":
        return {"type": "ewma", "window_size": window, "decay_rate": round(2 / (window + 1), 4),
                "deviation": "std_deviation"}
    raise ValueError(f"unknown filter type {kind!r}; expected one of {', '.join(FILTER_TYPES)}")


def config_with_filter(base: Path, kind: str, window: int) -> str:
    """``base`` (native format) with every observer's ``filter`` replaced."""
    data = yaml.safe_load(base.read_text(encoding="utf-8"))
    out = copy.deepcopy(data)
    for entry in out.get("observers", []):
        if isinstance(entry, dict) and "filter" in entry:
            entry["filter"] = filter_spec(kind, window)
    return yaml.safe_dump(out, sort_keys=False)


@dataclass(frozen=True, slots=True)
class FilterPoint:
    """One filter setting: alarms in the fault-free run, and on the campaign its false
    alarms, detected faults, faults and detection delays (seconds)."""

    filter: str
    window: int
    fault_free_alarms: int
    campaign_false_alarms: int
    detected: int
    faults: int
    delays: tuple[tuple[str, float], ...]
    """(fault kind, detection delay) of every detected fault."""

    def kind_delays(self, kinds: Sequence[str] = FILTERED_KINDS) -> list[float]:
        return sorted(d for k, d in self.delays if k in kinds)

    @property
    def delay_p50(self) -> float | None:
        """Median delay over the faults a filtered observer must see (rate and value)."""
        return percentile(self.kind_delays(), 50)

    def to_dict(self) -> dict[str, Any]:
        return {"filter": self.filter, "window": self.window,
                "fault_free_alarms": self.fault_free_alarms,
                "campaign_false_alarms": self.campaign_false_alarms,
                "detected": self.detected, "faults": self.faults,
                "filtered_kinds_delay_p50": self.delay_p50,
                "filtered_kinds_delay_p90": percentile(self.kind_delays(), 90),
                "all_kinds_delay_p50": percentile(self.kind_delays(tuple(
                    k for k, _ in self.delays)), 50)}


Progress = Callable[[str], None]


def _alarms(observations: Sequence[Observation], after: float) -> int:
    return sum(1 for e in episodes(o for o in observations if o.time >= after))


def _write(tmp: Path, kind: str, window: int, base: Path) -> Path:
    path = tmp / f"filter-{kind}-{window}.yaml"
    path.write_text(config_with_filter(base, kind, window), encoding="utf-8")
    return path


def simulated_filter_experiments(
    base: Path, tmp: Path, *, kinds: tuple[str, ...], runs: int = 2, duration: float = 300.0,
    fault_free: float = 100.0, seed: int = 0, settle: float = 5.0, grace: float = 2.0,
    filters: Sequence[str] = FILTER_TYPES, windows: Sequence[int] = WINDOW_SIZES,
    progress: Progress | None = None,
) -> list[FilterPoint]:
    """Every filter x window on the simulated thesis robot (simulated clock)."""
    points = []
    total = len(filters) * len(windows)
    for n, (kind, window) in enumerate((k, w) for k in filters for w in windows):
        config = _write(tmp, kind, window, base)
        sink = Collector()
        build(RunOptions(config=config, source="sim:thesis", duration=fault_free,
                         simulated_clock=True, seed=seed, live=False, diagnosis=False,
                         extra_sinks=[sink])).run()
        clean = _alarms(sink.observations, settle)
        scores = []
        for i in range(runs):
            run_sink = Collector()
            box = build(RunOptions(
                config=config, source="sim:thesis", duration=duration, simulated_clock=True,
                seed=seed + i, live=False, diagnosis=False, extra_sinks=[run_sink],
                faults=RandomFaults(duration - 5.0, kinds, mean_gap=10.0, warmup=5.0,
                                    min_separation=5.0)))
            robot: Any = box.pipeline.source
            stats = box.run()
            scores.append(score_run(robot.ground_truth, run_sink.observations,
                                    robot.topic_publishers(), start=stats.started,
                                    end=stats.ended, grace=grace))
        points.append(_point(kind, window, clean, scores))
        if progress is not None:
            progress(f"filters (simulator) {n + 1}/{total}: {kind} window {window}")
    return points


def _point(kind: str, window: int, clean: int, scores: Sequence[RunScore]) -> FilterPoint:
    outcomes = [o for s in scores for o in s.outcomes]
    return FilterPoint(kind, window, clean, sum(s.confusion.fp for s in scores),
                       sum(1 for o in outcomes if o.detected), len(outcomes),
                       tuple(sorted((o.fault.kind, o.delay) for o in outcomes
                                    if o.delay is not None)))


def replay(run: RealRun, config_text: str, name: str) -> list[Observation]:
    """The observations ``config_text`` makes from a recorded real run's events."""
    observers = build_observers(load_config_text(config_text, name))
    sink = Collector()
    started = run.stats.started
    pipeline = Pipeline(MemorySource(run.events, start_time=started), observers, [sink])
    pipeline.run(run.end - started)
    return sink.observations


def replayed_filter_experiments(
    base: Path, fault_free: RealRun, campaign: Sequence[RealRun], *, grace: float = 2.0,
    filters: Sequence[str] = FILTER_TYPES, windows: Sequence[int] = WINDOW_SIZES,
    progress: Progress | None = None,
) -> list[FilterPoint]:
    """Every filter x window over the same recorded real runs."""
    points = []
    total = len(filters) * len(windows)
    for n, (kind, window) in enumerate((k, w) for k in filters for w in windows):
        text = config_with_filter(base, kind, window)
        name = f"{base} with {kind} filter, window {window}"
        clean = _alarms(replay(fault_free, text, name), fault_free.start)
        scores = [score_run(r.truth, [o for o in replay(r, text, name) if o.time >= r.start],
                            r.publishers, start=r.start, end=r.end, grace=grace)
                  for r in campaign]
        points.append(_point(kind, window, clean, scores))
        if progress is not None:
            progress(f"filters (replayed real runs) {n + 1}/{total}: {kind} window {window}")
    return points
