"""Continuous consistency-based diagnosis of a robot from its observations.

The engine keeps the latest observation per observed characteristic (observer type and
resource). Each one contributes an assumption literal: OK, failed, or nothing at all when its
code is ``NOT_AVAILABLE`` (the observer has no data yet, so it is neither evidence of a fault
nor of health). Every other negative code counts as a failure.

When that assignment changes, the engine recomputes the minimal diagnoses with the HS-DAG
over conflicts from the SAT solver, reusing every earlier conflict whose supporting
observations still hold, and a cache of whole results for assignments seen before (a flapping
observation costs nothing).
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from blackbox.diagnose.hsdag import hs_dag
from blackbox.diagnose.robot_model import (
    NodeSpec,
    ObservationSpec,
    ObservedResource,
    RobotModel,
    TopicStructure,
    build_model,
    derive_robot_model,
    load_robot_model,
)
from blackbox.diagnose.sat import ConsistencyChecker, Theory
from blackbox.model import Code, Diagnosis, Observation, Resource
from blackbox.sources.base import GraphSnapshot

DEFAULT_PRIORS = {"node": 0.05, "hardware": 0.05, "topic": 0.01, "interface": 0.01}
"""Prior fault probability per component kind: with equal cardinality, a dead node is blamed
before the topic it publishes (the transport rarely fails on its own)."""

Key = tuple[str, Resource]


def observation_fact(code: Code) -> bool | None:
    """``True`` for OK, ``False`` for a failure, ``None`` for no evidence (NOT_AVAILABLE)."""
    if code == Code.NOT_AVAILABLE:
        return None
    return code >= 0


class DiagnosisEngine:
    """Minimal diagnoses of a :class:`RobotModel` under changing observations.

    ``priors`` maps component names (or kinds: ``node``, ``hardware``, ``topic``,
    ``interface``) to prior fault probabilities in (0, 1). ``max_cardinality`` bounds the
    size of a diagnosis, ``time_budget`` (seconds) the search of one re-diagnosis.
    """

    def __init__(self, model: RobotModel, priors: Mapping[str, float] | None = None, *,
                 max_cardinality: int | None = None, time_budget: float = 0.1,
                 cache_size: int = 256) -> None:
        self.priors = dict(priors or {})
        for name, p in self.priors.items():
            if not 0.0 < p < 1.0:
                raise ValueError(f"prior of {name!r} must be in (0, 1), got {p}")
        self.max_cardinality = max_cardinality
        self.time_budget = time_budget
        self._cache_size = cache_size
        self._latest: dict[Key, Observation] = {}
        self._current = Diagnosis(time=0.0, candidates=(), explanation="No observations yet.")
        self._build(model)

    # ---- construction ------------------------------------------------------------------------

    @classmethod
    def from_model_file(cls, path: str | Path, priors: Mapping[str, float] | None = None,
                        **kwargs: object) -> DiagnosisEngine:
        return cls(load_robot_model(path), priors, **kwargs)  # type: ignore[arg-type]

    @classmethod
    def from_graph(cls, graph: GraphSnapshot, observers: Sequence[ObservedResource],
                   priors: Mapping[str, float] | None = None, **kwargs: object
                   ) -> DiagnosisEngine:
        return cls(derive_robot_model(graph, observers), priors, **kwargs)  # type: ignore[arg-type]

    def _build(self, model: RobotModel) -> None:
        self.model = model
        self.structure = TopicStructure(model)
        th = Theory()
        self.theory = th
        for t in model.topics:
            ex = self.structure.producers(t, (), rate=True)
            th.add([th.var(("good", t)), *(th.ab(c) for c in ex.components),
                    *(-th.var(("good", i)) for i in ex.inputs)])
        self._slot: dict[Key, int] = {}
        mentions: dict[str, list[int]] = {}
        for spec in model.observations:
            ok = th.var(("ok", spec.key()))
            self._slot[spec.key()] = ok
            ex = self.structure.explain(spec)
            comps = ex.components
            if not comps and not ex.inputs:
                comps = tuple(t for t in (spec.resource.topic, spec.resource.topic_b) if t)
            th.add([ok, *(th.ab(c) for c in comps), *(-th.var(("good", i)) for i in ex.inputs)])
            for t in self.structure.mentions(spec):
                mentions.setdefault(t, []).append(ok)
        for t, oks in mentions.items():
            th.add([th.var(("good", t)), *(-ok for ok in oks)])
        self.checker = ConsistencyChecker(th, model.components)
        self._conflicts: dict[frozenset[str], frozenset[int]] = {}
        self._cache: OrderedDict[frozenset[int], tuple[tuple[frozenset[str], ...], bool]] = (
            OrderedDict())
        self._facts_key: frozenset[int] | None = None

    def _ensure_slot(self, obs: Observation) -> None:
        """Observations the model did not declare extend it (and rebuild the clauses)."""
        if obs.key() in self._slot:
            return
        r = obs.resource
        nodes = {n.name: n for n in self.model.nodes}
        extra = []
        if r.node and r.node not in nodes:
            extra.append(NodeSpec(r.node))
        spec = ObservationSpec(obs.observer, r)
        self._build(build_model([*self.model.nodes, *extra], [*self.model.observations, spec]))

    # ---- diagnosis ---------------------------------------------------------------------------

    def prior(self, component: str) -> float:
        p = self.priors.get(component)
        if p is None:
            kind = self.model.kind(component)
            p = self.priors.get(kind, DEFAULT_PRIORS[kind])
        return p

    def rank(self, sets: Iterable[frozenset[str]]) -> tuple[frozenset[str], ...]:
        """Cardinality first, then the larger prior odds product, then names."""
        def key(s: frozenset[str]) -> tuple[int, float, list[str]]:
            odds = sum(math.log(self.prior(c) / (1.0 - self.prior(c))) for c in s)
            return (len(s), -odds, sorted(s))
        return tuple(sorted(sets, key=key))

    def _facts(self) -> list[int]:
        facts = []
        for key, obs in self._latest.items():
            value = observation_fact(obs.code)
            if value is not None:
                ok = self._slot[key]
                facts.append(ok if value else -ok)
        return sorted(facts)

    def _search(self, facts: list[int]) -> tuple[tuple[frozenset[str], ...], bool]:
        key = frozenset(facts)
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        deadline = time.perf_counter() + self.time_budget
        reusable = [c for c, support in self._conflicts.items() if support <= key]

        def prover(path: frozenset[str]) -> frozenset[str] | None:
            conflict = self.checker.conflict(facts, path, deadline)
            if conflict is None:
                return None
            self._conflicts[conflict.components] = conflict.support
            return conflict.components

        res = hs_dag(prover, conflicts=reusable, max_cardinality=self.max_cardinality,
                     deadline=deadline)
        out = (self.rank(res.sets), res.complete)
        if res.complete:
            self._cache[key] = out
            if len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return out

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
        """Feed new observations; a new :class:`Diagnosis` when the failed observations or the
        diagnoses changed, else ``None``."""
        for obs in observations:
            self._ensure_slot(obs)
            self._latest[obs.key()] = obs
        facts = self._facts()
        fkey = frozenset(facts)
        if fkey == self._facts_key:
            return None
        self._facts_key = fkey
        failed = tuple(sorted((o for o in self._latest.values()
                               if observation_fact(o.code) is False),
                              key=lambda o: (o.observer, o.resource.label())))
        if failed:
            candidates, complete = self._search(facts)
        else:
            candidates, complete = (), True
        previous = self._current
        if (candidates == previous.candidates and complete == previous.complete
                and [o.key() for o in failed] == [o.key() for o in previous.failed]
                and previous.time > 0.0):
            return None
        self._current = Diagnosis(now, candidates, failed,
                                  self.explain(candidates, failed, complete), complete)
        return self._current

    def current(self) -> Diagnosis:
        return self._current

    # ---- words -------------------------------------------------------------------------------

    def _name(self, component: str) -> str:
        kind = self.model.kind(component)
        if kind == "interface":
            return f"network interface {component.removeprefix('iface:')}"
        return f"{kind} {component}"

    def _set_words(self, s: frozenset[str]) -> str:
        return " and ".join(self._name(c) for c in sorted(s))

    def explain(self, candidates: Sequence[frozenset[str]], failed: Sequence[Observation],
                complete: bool) -> str:
        """One paragraph a technician can act on."""
        total = len(self._latest)
        if not failed:
            return f"All {total} current observations are OK; no component is suspected."
        listed = "; ".join(f"{o.observer} on {o.resource.label()} ({o.code.name})"
                           for o in failed[:6])
        more = f" and {len(failed) - 6} more" if len(failed) > 6 else ""
        text = f"{len(failed)} of {total} observations failed: {listed}{more}. "
        if not candidates:
            if complete:
                text += ("No set of modelled components explains them"
                         + (f" with at most {self.max_cardinality} faults" if
                            self.max_cardinality else "")
                         + "; check the model or the observer configuration.")
            else:
                text += "The search ran out of its time budget before finding an explanation."
            return text
        best = candidates[0]
        verb = "is" if len(best) == 1 else "are"
        text += (f"Most likely {self._set_words(best)} {verb} faulty, which explains every "
                 f"failed observation")
        healthy = sum(observation_fact(o.code) is True for o in self._latest.values())
        text += f" and agrees with the {healthy} healthy ones. " if healthy else ". "
        if len(candidates) > 1:
            alts = "; ".join(self._set_words(c) for c in candidates[1:4])
            extra = f" (and {len(candidates) - 4} more)" if len(candidates) > 4 else ""
            text += f"Other minimal explanations: {alts}{extra}. "
        else:
            text += "No other explanation of the same or smaller size exists. "
        if not complete:
            text += "The search stopped at its time budget, so the list may be incomplete."
        return text.strip()
