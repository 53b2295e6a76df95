"""Scoring detections against injected faults: confusion counts and the thesis's measures.

The units, fixed here once and described in ``docs/evaluation.md``:

- a **fault** is one :class:`GroundTruth` record; it *belongs to* a set of components: a
  node fault to its node and every topic the node publishes, a topic fault to the topic and
  its publisher node;
- an observation is *related* to a fault when its resource (node, topic, second topic or
  publisher group) names one of the fault's components;
- an **episode** is a maximal run of consecutive faulty observations (code < 0) of one
  observer key (observer type and resource); an observation left unjudged for a
  measurement gap (the black box's own blind spot, docs/observations.md) is no alarm and
  neither starts nor ends one;
- **TP**: a fault with a related episode that *starts* inside its window
  ``[start, end + grace]``; the delay is the start of the earliest such episode minus the
  fault's start. **FN**: every other fault;
- **FP**: an episode that overlaps no window of a related fault;
- **TN**: a non-faulty observation (one evaluation of one observer key, 1 Hz in the shipped
  configurations) at a time when no related fault's window is open.

TP and FN count faults, FP counts episodes and TN counts evaluations, so accuracy depends on
the TN unit; precision, recall and F1 do not involve TN at all.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from blackbox.model import Diagnosis, Observation, Resource
from blackbox.observe.gaps import unmeasured
from blackbox.sources.sim import FAULT_KINDS, GroundTruth

DEFAULT_GRACE = 2.0
"""Seconds after a fault's end during which observations still count as seeing it: filters
average over a window, so a verdict lags the physical change."""

Key = tuple[str, Resource]


def _ratio(num: int, den: int) -> float | None:
    return num / den if den else None


@dataclass(frozen=True, slots=True)
class Confusion:
    """Confusion counts and the measures of thesis eqs. 6.1-6.4.

    A measure whose denominator is zero is ``None`` (undefined), never a made-up 0 or 1.
    """

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    def __add__(self, other: Confusion) -> Confusion:
        return Confusion(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn,
                         self.tn + other.tn)

    @property
    def accuracy(self) -> float | None:
        """Eq. 6.1: (TP + TN) / (TP + TN + FP + FN)."""
        return _ratio(self.tp + self.tn, self.tp + self.tn + self.fp + self.fn)

    @property
    def accuracy_without_tn(self) -> float | None:
        """Eq. 6.1 with TN = 0, i.e. TP / (TP + FP + FN): the thesis's reported accuracies
        (71.64 % = 240 / 335, 88 % = 276 / 311) are exactly this value."""
        return _ratio(self.tp, self.tp + self.fp + self.fn)

    @property
    def precision(self) -> float | None:
        """Eq. 6.2: TP / (TP + FP)."""
        return _ratio(self.tp, self.tp + self.fp)

    @property
    def recall(self) -> float | None:
        """Eq. 6.3: TP / (TP + FN)."""
        return _ratio(self.tp, self.tp + self.fn)

    @property
    def f1(self) -> float | None:
        """Eq. 6.4: 2 * precision * recall / (precision + recall)."""
        p, r = self.precision, self.recall
        if p is None or r is None or p + r == 0:
            return None
        return 2 * p * r / (p + r)

    def to_dict(self) -> dict[str, Any]:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "tn": self.tn,
                "accuracy": self.accuracy, "accuracy_without_tn": self.accuracy_without_tn,
                "precision": self.precision, "recall": self.recall, "f1": self.f1}


@dataclass(frozen=True, slots=True)
class ThesisResult:
    """A results table of the thesis: its counts and the measures as printed."""

    name: str
    injected: int
    confusion: Confusion
    accuracy: float
    precision: float
    recall: float
    f1: float


THESIS_BEFORE = ThesisResult("thesis tests 1-10 (Table 6.7)", 260, Confusion(240, 60, 35),
                             0.7164, 0.80, 0.88, 0.83)
THESIS_AFTER = ThesisResult("thesis tests 11-20, re-tuned (Table 6.8)", 290,
                            Confusion(276, 23, 12), 0.88, 0.92, 0.96, 0.93)


@dataclass(frozen=True, slots=True)
class Episode:
    """Consecutive faulty observations of one observer key, first to last."""

    key: Key
    start: float
    end: float
    count: int


def episodes(observations: Iterable[Observation]) -> list[Episode]:
    """Every episode in the observations (in time order per key), sorted by start time."""
    open_: dict[Key, list[float]] = {}
    found: list[Episode] = []
    for obs in sorted(observations, key=lambda o: o.time):
        if unmeasured(obs):
            continue
        key = obs.key()
        run = open_.get(key)
        if obs.faulty:
            if run is None:
                open_[key] = [obs.time, obs.time, 1]
            else:
                run[1] = obs.time
                run[2] += 1
        elif run is not None:
            found.append(Episode(key, run[0], run[1], int(run[2])))
            del open_[key]
    found.extend(Episode(k, r[0], r[1], int(r[2])) for k, r in open_.items())
    return sorted(found, key=lambda e: (e.start, e.key[0], e.key[1].label()))


def resource_components(resource: Resource) -> frozenset[str]:
    """The node and topic names an observation is about."""
    names = {resource.node, resource.topic, resource.topic_b, *resource.publishers}
    return frozenset(n for n in names if n)


def fault_components(fault: GroundTruth, publishers: Mapping[str, str]) -> frozenset[str]:
    """What a fault belongs to: a node and its topics, or a topic and its publisher node.

    ``publishers`` maps each topic to its publisher node.
    """
    if FAULT_KINDS[fault.kind].target == "node":
        return frozenset({fault.component, *(t for t, n in publishers.items()
                                             if n == fault.component)})
    return frozenset({fault.component, fault.node})


@dataclass(frozen=True, slots=True)
class FaultOutcome:
    """One scored fault; ``end`` is resolved to the run's end for a fault still active."""

    fault: GroundTruth
    end: float
    detected: bool
    delay: float | None = None
    detected_by: Key | None = None
    isolated: bool | None = None
    isolation_delay: float | None = None
    in_candidates: bool | None = None

    def to_dict(self) -> dict[str, Any]:
        by = None
        if self.detected_by is not None:
            by = {"observer": self.detected_by[0], "resource": self.detected_by[1].to_dict()}
        return {**self.fault.to_dict(), "end": self.end, "detected": self.detected,
                "delay": self.delay, "detected_by": by, "isolated": self.isolated,
                "isolation_delay": self.isolation_delay, "in_candidates": self.in_candidates}


@dataclass(frozen=True, slots=True)
class DiagnosisScore:
    """How the diagnoses named the faulty components.

    A fault is *isolated* (top-1) when a diagnosis inside its window ranks first a candidate
    that contains one of the fault's components, and *in the candidates* when a diagnosis
    inside its window lists, at any rank, a candidate that contains one (what a sound
    diagnosis must do once the fault is seen). A diagnosis with candidates is *correct* when
    its first candidate contains a component of a fault whose window is open at its time,
    else *wrong* (a false alarm or a wrong component).
    """

    faults: int = 0
    isolated: int = 0
    correct: int = 0
    wrong: int = 0
    in_candidates: int = 0

    def __add__(self, other: DiagnosisScore) -> DiagnosisScore:
        return DiagnosisScore(self.faults + other.faults, self.isolated + other.isolated,
                              self.correct + other.correct, self.wrong + other.wrong,
                              self.in_candidates + other.in_candidates)

    @property
    def isolation_rate(self) -> float | None:
        """Top-1: faults whose component a diagnosis ranked first, over all faults."""
        return _ratio(self.isolated, self.faults)

    @property
    def candidate_rate(self) -> float | None:
        """Soundness: faults whose component a diagnosis listed at all, over all faults."""
        return _ratio(self.in_candidates, self.faults)

    @property
    def diagnosis_precision(self) -> float | None:
        return _ratio(self.correct, self.correct + self.wrong)

    def to_dict(self) -> dict[str, Any]:
        return {"faults": self.faults, "isolated": self.isolated, "correct": self.correct,
                "wrong": self.wrong, "isolation_rate": self.isolation_rate,
                "in_candidates": self.in_candidates, "candidate_rate": self.candidate_rate,
                "diagnosis_precision": self.diagnosis_precision}


@dataclass(frozen=True, slots=True)
class RunScore:
    """Everything scored about one run."""

    start: float
    end: float
    grace: float
    outcomes: tuple[FaultOutcome, ...]
    episodes: tuple[Episode, ...]
    false_positives: tuple[Episode, ...]
    confusion: Confusion
    diagnosis: DiagnosisScore | None = None

    def delays(self, kind: str | None = None) -> list[float]:
        return [o.delay for o in self.outcomes
                if o.delay is not None and (kind is None or o.fault.kind == kind)]

    def to_dict(self) -> dict[str, Any]:
        return {
            "start": self.start, "end": self.end, "grace": self.grace,
            "confusion": self.confusion.to_dict(),
            "faults": [o.to_dict() for o in self.outcomes],
            "false_positives": [{"observer": e.key[0], "resource": e.key[1].to_dict(),
                                 "start": e.start, "end": e.end, "observations": e.count}
                                for e in self.false_positives],
            "diagnosis": None if self.diagnosis is None else self.diagnosis.to_dict(),
        }


@dataclass(frozen=True, slots=True)
class _Window:
    components: frozenset[str]
    start: float
    end: float

    def contains(self, t: float) -> bool:
        return self.start <= t <= self.end

    def overlaps(self, start: float, end: float) -> bool:
        return start <= self.end and self.start <= end


def score_run(
    faults: Sequence[GroundTruth],
    observations: Sequence[Observation],
    publishers: Mapping[str, str],
    *,
    start: float,
    end: float,
    grace: float = DEFAULT_GRACE,
    diagnoses: Sequence[Diagnosis] | None = None,
) -> RunScore:
    """Score one run from ``start`` to ``end`` (the run's clock) against its ground truth.

    ``publishers`` maps topics to their publisher nodes (the robot's topology). Pass
    ``diagnoses`` to score isolation as well.
    """
    if not (math.isfinite(grace) and grace >= 0):
        raise ValueError(f"grace must be a number of seconds >= 0, got {grace!r}")
    windows = [_Window(fault_components(f, publishers), f.start,
                       (end if f.end is None else min(f.end, end)) + grace) for f in faults]
    found = episodes(observations)
    related: dict[Key, list[int]] = {}
    for e in found:
        if e.key not in related:
            comps = resource_components(e.key[1])
            related[e.key] = [i for i, w in enumerate(windows) if w.components & comps]

    first: dict[int, Episode] = {}
    false_positives: list[Episode] = []
    for e in found:
        mine = related[e.key]
        for i in mine:
            if windows[i].contains(e.start) and i not in first:
                first[i] = e
        if not any(windows[i].overlaps(e.start, e.end) for i in mine):
            false_positives.append(e)

    tn = 0
    key_windows: dict[Key, list[_Window]] = {}
    for obs in observations:
        if obs.faulty:
            continue
        ws = key_windows.get(obs.key())
        if ws is None:
            comps = resource_components(obs.resource)
            ws = key_windows[obs.key()] = [w for w in windows if w.components & comps]
        if not any(w.contains(obs.time) for w in ws):
            tn += 1

    isolation = _isolation(windows, diagnoses) if diagnoses is not None else None
    outcomes = []
    for i, f in enumerate(faults):
        hit = first.get(i)
        iso = None if isolation is None else isolation[0].get(i)
        outcomes.append(FaultOutcome(
            f, end if f.end is None else min(f.end, end), hit is not None,
            None if hit is None else hit.start - f.start, None if hit is None else hit.key,
            None if isolation is None else iso is not None,
            None if iso is None else iso - f.start,
            None if isolation is None else i in isolation[3]))
    tp = len(first)
    confusion = Confusion(tp=tp, fp=len(false_positives), fn=len(faults) - tp, tn=tn)
    diagnosis = None
    if isolation is not None:
        diagnosis = DiagnosisScore(len(faults), len(isolation[0]), isolation[1], isolation[2],
                                   len(isolation[3]))
    return RunScore(start, end, grace, tuple(outcomes), tuple(found), tuple(false_positives),
                    confusion, diagnosis)


def _isolation(windows: Sequence[_Window], diagnoses: Sequence[Diagnosis]
               ) -> tuple[dict[int, float], int, int, set[int]]:
    """First isolating diagnosis time per fault index, correct/wrong diagnosis counts, and
    the fault indices some diagnosis listed among its candidates."""
    isolated: dict[int, float] = {}
    listed: set[int] = set()
    correct = wrong = 0
    for d in sorted(diagnoses, key=lambda d: d.time):
        if not d.candidates:
            continue
        named = frozenset().union(*d.candidates)
        listed.update(i for i, w in enumerate(windows)
                      if w.contains(d.time) and w.components & named)
        top = d.candidates[0]
        hits = [i for i, w in enumerate(windows) if w.contains(d.time) and w.components & top]
        if hits:
            correct += 1
        else:
            wrong += 1
        for i in hits:
            isolated.setdefault(i, d.time)
    return isolated, correct, wrong, listed


@dataclass(frozen=True, slots=True)
class KindSummary:
    """Detection per fault kind over one or more runs."""

    kind: str
    faults: int
    detected: int
    delays: tuple[float, ...] = field(default=())

    @property
    def recall(self) -> float | None:
        return _ratio(self.detected, self.faults)


def by_kind(outcomes: Iterable[FaultOutcome]) -> list[KindSummary]:
    """Faults, detections and detection delays per kind, in ``FAULT_KINDS`` order."""
    groups: dict[str, list[FaultOutcome]] = defaultdict(list)
    for o in outcomes:
        groups[o.fault.kind].append(o)
    order = {k: i for i, k in enumerate(FAULT_KINDS)}
    return [KindSummary(k, len(g), sum(o.detected for o in g),
                        tuple(sorted(o.delay for o in g if o.delay is not None)))
            for k, g in sorted(groups.items(), key=lambda kv: order.get(kv[0], len(order)))]


@dataclass(frozen=True, slots=True)
class IsolationSummary:
    """Isolation per fault kind: top-1 (``isolated``) and soundness (``in_candidates``)."""

    kind: str
    faults: int
    isolated: int
    in_candidates: int

    @property
    def isolation_rate(self) -> float | None:
        return _ratio(self.isolated, self.faults)

    @property
    def candidate_rate(self) -> float | None:
        return _ratio(self.in_candidates, self.faults)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "faults": self.faults, "isolated": self.isolated,
                "isolation_rate": self.isolation_rate, "in_candidates": self.in_candidates,
                "candidate_rate": self.candidate_rate}


def isolation_by_kind(outcomes: Iterable[FaultOutcome]) -> list[IsolationSummary]:
    """Both isolation figures per kind, in ``FAULT_KINDS`` order; faults scored without
    diagnoses are left out."""
    groups: dict[str, list[FaultOutcome]] = defaultdict(list)
    for o in outcomes:
        if o.isolated is not None:
            groups[o.fault.kind].append(o)
    order = {k: i for i, k in enumerate(FAULT_KINDS)}
    return [IsolationSummary(k, len(g), sum(bool(o.isolated) for o in g),
                             sum(bool(o.in_candidates) for o in g))
            for k, g in sorted(groups.items(), key=lambda kv: order.get(kv[0], len(order)))]


def percentile(values: Sequence[float], q: float) -> float | None:
    """Nearest-rank percentile (``q`` in [0, 100]) of ``values``; ``None`` when empty.

    Nearest rank returns a value that occurred, which suits a handful of detection delays
    better than interpolation.
    """
    if not values:
        return None
    ordered = sorted(values)
    rank = max(1, math.ceil(q / 100.0 * len(ordered)))
    return ordered[rank - 1]
