"""Fault-injection campaigns: seeded random faults through the real pipeline, scored.

The experiment of thesis section 6.2.1.2 (ten runs of five minutes with random faults),
repeated on the simulated robot: each run draws a random campaign, runs the configured
observers and the diagnosis over the simulator's clock (five minutes take well under a
second) and scores the observations and diagnoses against the simulator's ground truth.
A source without a simulated clock but with a registered robot harness (``ros1``: the real
demo robot) runs the same campaign on real processes in real time
(:mod:`blackbox.evaluate.real_campaign`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from blackbox.app import DEFAULT_CONFIG, RunOptions, build
from blackbox.config.node import ConfigError
from blackbox.evaluate.engine_score import diagnosis_observations
from blackbox.evaluate.metrics import (
    DEFAULT_GRACE,
    THESIS_AFTER,
    THESIS_BEFORE,
    Confusion,
    DiagnosisScore,
    FaultOutcome,
    KindSummary,
    RunScore,
    by_kind,
    percentile,
    score_run,
)
from blackbox.evaluate.real_campaign import (
    ROBOT_HARNESSES,
    RealRun,
    ResourceUse,
    RobotHarness,
    run_real,
)
from blackbox.pipeline import RunStats
from blackbox.sinks import Collector
from blackbox.sources.base import (
    Capabilities,
    GroundTruthSource,
    RandomFaults,
    scheme_of,
    source_kind,
)
from blackbox.sources.sim import FAULT_KINDS, THESIS_FAULT_KINDS

KIND_SETS: Mapping[str, tuple[str, ...]] = {"thesis": THESIS_FAULT_KINDS,
                                            "all": tuple(FAULT_KINDS), "none": ()}
"""Named sets of fault kinds for ``--kinds``. ``none`` injects nothing: a healthy run, in
which every alarm is a false one (the healthy hours of docs/evaluation.md)."""


def parse_kinds(text: str) -> tuple[str, ...]:
    """``thesis``, ``all``, ``none`` (a healthy run) or a comma-separated list of kinds."""
    if text in KIND_SETS:
        return KIND_SETS[text]
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    unknown = [k for k in kinds if k not in FAULT_KINDS]
    if not kinds or unknown:
        raise ValueError(f"--kinds: unknown fault kind {unknown[0] if unknown else text!r}; "
                         f"expected thesis, all, none or a comma-separated list of "
                         f"{', '.join(FAULT_KINDS)}")
    return kinds


@dataclass(frozen=True)
class CampaignSettings:
    """What to run: ``runs`` runs of ``duration`` simulated seconds, run ``i`` with seed
    ``seed + i`` for both its faults and the simulator's noise.

    Faults start as a Poisson process with ``mean_gap`` seconds between starts, after a
    ``warmup`` and no later than ``tail`` seconds before the end (so every fault can be seen);
    two faults on one node are ``separation`` seconds apart at least, so each is a separate
    event for the observers rather than one long alarm.
    """

    config: Path = DEFAULT_CONFIG
    source: str = "sim:thesis"
    runs: int = 10
    duration: float = 300.0
    seed: int = 0
    kinds: tuple[str, ...] = THESIS_FAULT_KINDS
    grace: float = DEFAULT_GRACE
    separation: float = 5.0
    mean_gap: float = 10.0
    warmup: float = 5.0
    tail: float = 5.0
    diagnosis: bool = True
    engine: str | None = None
    """``cbd``, ``sfdd`` or ``hybrid`` (``--engine``); ``None``: the configuration's."""

    def check(self) -> None:
        """Raise ``ValueError`` naming the bad option (``--runs: ...``)."""
        if self.runs < 1:
            raise ValueError(f"--runs: need at least one run, got {self.runs}")
        for name, value in (("grace", self.grace), ("separation", self.separation),
                            ("mean-gap", self.mean_gap), ("duration", self.duration),
                            ("warmup", self.warmup), ("tail", self.tail)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"--{name}: must be a number >= 0, got {value!r}")
        if self.mean_gap <= 0:
            raise ValueError("--mean-gap: must be > 0")
        if self.duration - self.tail <= self.warmup:
            raise ValueError(f"--duration: a run must last more than "
                             f"{self.warmup + self.tail:g} s ({self.warmup:g} s warm-up + "
                             f"{self.tail:g} s without new faults at the end)")
        caps = source_capabilities(self.source)
        simulated = caps.fault_injection and caps.ground_truth and caps.simulated_clock
        if not simulated and self.harness() is not None and self.source != scheme_of(self.source):
            raise ValueError(f"--source: a campaign starts its own demo robot; give "
                             f"{scheme_of(self.source)} alone, not {self.source!r}")
        if not simulated and self.harness() is None:
            raise ValueError("--source: campaigns need a simulated robot (sim:...) or a source "
                             "with a demo robot and fault injector (" +
                             ", ".join(ROBOT_HARNESSES) + ")")
        if self.engine is not None and self.engine not in ("cbd", "sfdd", "hybrid"):
            raise ValueError(f"--engine: expected cbd, sfdd or hybrid, got {self.engine!r}")
        unknown = [k for k in self.kinds if k not in FAULT_KINDS]
        if unknown:
            raise ValueError(f"--kinds: unknown fault kind {unknown[0]!r}")

    def harness(self) -> RobotHarness | None:
        """The demo robot harness for a real-time source (``None`` for a simulated one)."""
        if source_capabilities(self.source).simulated_clock:
            return None
        return ROBOT_HARNESSES.get(scheme_of(self.source))

    def to_dict(self) -> dict[str, Any]:
        return {"config": str(self.config), "source": self.source, "runs": self.runs,
                "duration": self.duration, "seed": self.seed, "kinds": list(self.kinds),
                "grace": self.grace, "separation": self.separation, "mean_gap": self.mean_gap,
                "warmup": self.warmup, "tail": self.tail, "diagnosis": self.diagnosis,
                "engine": self.engine}


@dataclass(frozen=True)
class RunResult:
    """One scored run. ``wall`` is the wall-clock seconds it took (for progress only)."""

    index: int
    seed: int
    score: RunScore
    stats: RunStats
    wall: float
    engine_score: RunScore | None = None
    """The engine's diagnoses scored as detections (:mod:`.engine_score`)."""
    engine_cpu: float | None = None
    """CPU seconds of the diagnosis engine (and SFDD's signal tap) over the run; like
    ``wall`` it varies between identical runs, so it is printed, not in :meth:`to_dict`."""
    real: RealRun | None = None
    """The recorded real run (events, ground truth, resource use) on real middleware."""

    @property
    def resources(self) -> ResourceUse | None:
        return None if self.real is None else self.real.resources

    def to_dict(self) -> dict[str, Any]:
        out = {"index": self.index, "seed": self.seed, **self.score.to_dict(),
               "messages": self.stats.messages, "observations": self.stats.observations,
               "faulty_observations": self.stats.faulty_observations,
               "diagnoses": self.stats.diagnoses, "errors": self.stats.errors}
        if self.engine_score is not None:
            out["engine_score"] = {
                "confusion": self.engine_score.confusion.to_dict(),
                "diagnosis": None if self.engine_score.diagnosis is None
                else self.engine_score.diagnosis.to_dict()}
        if self.resources is not None:
            out["blackbox_resources"] = self.resources.to_dict()
        if self.real is not None:
            out["gaps"] = self.real.gaps()
            out["source_reports"] = self.real.reports()
        return out


@dataclass(frozen=True)
class CampaignResult:
    settings: CampaignSettings
    runs: tuple[RunResult, ...] = field(default=())

    @property
    def confusion(self) -> Confusion:
        total = Confusion()
        for r in self.runs:
            total = total + r.score.confusion
        return total

    @property
    def diagnosis(self) -> DiagnosisScore | None:
        scores = [r.score.diagnosis for r in self.runs if r.score.diagnosis is not None]
        if not scores:
            return None
        total = DiagnosisScore()
        for s in scores:
            total = total + s
        return total

    @property
    def outcomes(self) -> list[FaultOutcome]:
        return [o for r in self.runs for o in r.score.outcomes]

    @property
    def kinds(self) -> list[KindSummary]:
        return by_kind(self.outcomes)

    def delays(self) -> list[float]:
        return sorted(o.delay for o in self.outcomes if o.delay is not None)

    def engine_totals(self) -> tuple[Confusion, DiagnosisScore, list[float], float] | None:
        """The engine's detections summed over runs: confusion, isolation, delays, CPU s."""
        scores = [r.engine_score for r in self.runs if r.engine_score is not None]
        if not scores:
            return None
        confusion, iso = Confusion(), DiagnosisScore()
        for s in scores:
            confusion = confusion + s.confusion
            if s.diagnosis is not None:
                iso = iso + s.diagnosis
        delays = sorted(d for s in scores for d in s.delays())
        return confusion, iso, delays, sum(r.engine_cpu or 0.0 for r in self.runs)

    @property
    def resources(self) -> ResourceUse | None:
        """The black box's CPU and RSS over every real run (``None`` on the simulator)."""
        uses = [r.resources for r in self.runs if r.resources is not None]
        if not uses:
            return None
        seconds = sum(u.seconds for u in uses)
        return ResourceUse(sum(u.cpu_percent * u.seconds for u in uses) / seconds,
                           sum(u.rss_mean * u.seconds for u in uses) / seconds,
                           max(u.rss_max for u in uses), seconds)

    def to_dict(self) -> dict[str, Any]:
        delays = self.delays()
        iso = [o.isolation_delay for o in self.outcomes if o.isolation_delay is not None]
        return {
            "settings": self.settings.to_dict(),
            "totals": {
                "faults": len(self.outcomes), **self.confusion.to_dict(),
                "delay": delay_summary(delays),
                "diagnosis": None if self.diagnosis is None else {
                    **self.diagnosis.to_dict(), "isolation_delay": delay_summary(iso)},
            },
            "kinds": [{"kind": k.kind, "faults": k.faults, "detected": k.detected,
                       "recall": k.recall, "delay": delay_summary(k.delays)}
                      for k in self.kinds],
            "thesis": [{"name": t.name, "injected": t.injected, **t.confusion.to_dict(),
                        "printed": {"accuracy": t.accuracy, "precision": t.precision,
                                    "recall": t.recall, "f1": t.f1}}
                       for t in (THESIS_BEFORE, THESIS_AFTER)],
            "runs": [r.to_dict() for r in self.runs],
            "blackbox_resources": None if self.resources is None else self.resources.to_dict(),
        }


def delay_summary(delays: Sequence[float]) -> dict[str, float | int | None]:
    return {"count": len(delays), "p50": percentile(delays, 50),
            "p90": percentile(delays, 90), "max": max(delays) if delays else None}


def source_capabilities(spec: str) -> Capabilities:
    """The capabilities of the source ``spec`` names; ``ValueError`` for an unknown one."""
    try:
        return source_kind(spec).capabilities
    except ConfigError as exc:
        raise ValueError(f"--source: {exc.message}") from None


def run_one(settings: CampaignSettings, index: int,
            tick: Callable[[float], None] | None = None) -> RunResult:
    """Run and score run ``index`` of a campaign. Raises ``ValueError`` for a bad option or
    source and :class:`ConfigError` for a bad configuration file."""
    started = time.perf_counter()
    seed = settings.seed + index
    harness = settings.harness()
    if harness is not None:
        real = run_real(harness, config=Path(settings.config), duration=settings.duration,
                        tail=settings.tail, seed=seed, kinds=settings.kinds,
                        mean_gap=settings.mean_gap, warmup=settings.warmup,
                        separation=settings.separation, diagnosis=settings.diagnosis,
                        tick=tick)
        score = score_run(real.truth, real.observations, real.publishers, start=real.start,
                          end=real.end, grace=settings.grace,
                          diagnoses=real.diagnoses if settings.diagnosis else None)
        return RunResult(index, seed, score, real.stats, time.perf_counter() - started,
                         real=real)
    # No kinds is a healthy run; RandomFaults would read an empty tuple as "every kind".
    faults = RandomFaults(settings.duration - settings.tail, settings.kinds,
                          mean_gap=settings.mean_gap, warmup=settings.warmup,
                          min_separation=settings.separation) if settings.kinds else None
    sink = Collector()
    try:
        box = build(RunOptions(config=Path(settings.config), source=settings.source,
                               duration=settings.duration, simulated_clock=True, faults=faults,
                               seed=seed, live=False, diagnosis=settings.diagnosis,
                               extra_sinks=[sink], engine=settings.engine))
    except ConfigError as exc:
        if exc.file != "--source":
            raise
        raise ValueError(f"--source: {exc.message}") from None
    robot = cast(GroundTruthSource, box.pipeline.source)
    stats = box.run()
    diagnosed = box.pipeline.diagnoser is not None
    score = score_run(robot.ground_truth, sink.observations, robot.topic_publishers(),
                      start=stats.started, end=stats.ended, grace=settings.grace,
                      diagnoses=sink.diagnoses if diagnosed else None)
    engine_score = engine_cpu = None
    if diagnosed:
        publishers = robot.topic_publishers()
        engine_score = score_run(
            robot.ground_truth, diagnosis_observations(sink.diagnoses, publishers, stats.ended),
            publishers, start=stats.started, end=stats.ended, grace=settings.grace,
            diagnoses=sink.diagnoses)
        engine_cpu = float(getattr(box.pipeline.diagnoser, "cpu_seconds", 0.0)) + sum(
            float(getattr(o, "cpu_seconds", 0.0)) for o in box.pipeline.observers
            if getattr(o, "type_name", "") == "sfdd")
    return RunResult(index, seed, score, stats, time.perf_counter() - started, engine_score,
                     engine_cpu)


def run_campaign(settings: CampaignSettings,
                 progress: Callable[[RunResult], None] | None = None,
                 tick: Callable[[int, float], None] | None = None) -> CampaignResult:
    """Run every run of ``settings`` in turn, calling ``progress`` after each and, on a real
    robot, ``tick(run index, seconds so far)`` every ten seconds while a run is under way."""
    settings.check()
    results = []
    for i in range(settings.runs):
        run_tick = None if tick is None else _bind(tick, i)
        result = run_one(settings, i, run_tick)
        results.append(result)
        if progress is not None:
            progress(result)
    return CampaignResult(settings, tuple(results))


def _bind(tick: Callable[[int, float], None], index: int) -> Callable[[float], None]:
    return lambda seconds: tick(index, seconds)
