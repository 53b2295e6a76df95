"""Continuous consistency-based diagnosis of a robot from its observations.

The engine keeps the latest observation per observed characteristic (observer type and
resource). Each one contributes an assumption literal: OK, failed, or nothing at all when its
code is ``NOT_AVAILABLE`` (the observer has no data yet, so it is neither evidence of a fault
nor of health). Every other negative code counts as a failure.

Fault propagation through a node depends on the failure mode (``docs/diagnosis.md``). Whether
a node's output rate needs an input is an assumption literal per edge (``depends``): fixed by
configuration, or learnt: once the node has been seen publishing at rate for
``learn_after`` seconds while that input was silent, the edge no longer carries silence.

When that assignment changes, the engine recomputes the minimal diagnoses with the HS-DAG
over conflicts from the SAT solver, reusing every earlier conflict whose supporting
observations still hold, and a cache of whole results for assignments seen before (a flapping
observation costs nothing).
"""

from __future__ import annotations

import itertools
import math
import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from blackbox.diagnose.hsdag import hs_dag
from blackbox.diagnose.robot_model import (
    Edge,
    Explanation,
    NodeSpec,
    ObservationSpec,
    ObservedResource,
    Propagation,
    RobotModel,
    TopicStructure,
    build_model,
    derive_robot_model,
    is_rate_type,
    load_robot_model,
)
from blackbox.diagnose.sat import ConsistencyChecker, Theory
from blackbox.events import GraphSnapshot
from blackbox.model import Code, Diagnosis, Observation, Resource

DEFAULT_PRIORS = {"node": 0.05, "hardware": 0.05, "topic": 0.01, "interface": 0.01}
"""Prior fault probability per component kind: with equal cardinality, a dead node is blamed
before the topic it publishes (the transport rarely fails on its own)."""

Key = tuple[str, Resource]
Watch = tuple[Edge, list[Key], list[Key], list[Key]]


def observation_fact(code: Code) -> bool | None:
    """``True`` for OK, ``False`` for a failure, ``None`` for no evidence (NOT_AVAILABLE)."""
    fact = _FACT_OF.get(code, _UNKNOWN)
    if fact is not _UNKNOWN:
        return fact  # type: ignore[return-value]
    if code == Code.NOT_AVAILABLE:
        return None
    return code >= 0


_UNKNOWN = object()
_FACT_OF: dict[object, bool | None] = {c: None if c == Code.NOT_AVAILABLE else c >= 0
                                        for c in Code}


class DiagnosisEngine:
    """Minimal diagnoses of a :class:`RobotModel` under changing observations.

    ``priors`` maps component names (or kinds: ``node``, ``hardware``, ``topic``,
    ``interface``) to prior fault probabilities in (0, 1). ``max_cardinality`` bounds the
    size of a diagnosis, ``time_budget`` (seconds) the search of one re-diagnosis.
    ``propagation`` says how input faults reach a node's outputs; ``independent`` are edges
    already learnt not to carry silence (an engine rebuilt for a changed graph keeps them).
    """

    def __init__(self, model: RobotModel, priors: Mapping[str, float] | None = None, *,
                 max_cardinality: int | None = None, time_budget: float = 0.1,
                 cache_size: int = 256, propagation: Propagation | None = None,
                 independent: Iterable[Edge] = ()) -> None:
        self.priors = dict(priors or {})
        for name, p in self.priors.items():
            if not 0.0 < p < 1.0:
                raise ValueError(f"prior of {name!r} must be in (0, 1), got {p}")
        self.max_cardinality = max_cardinality
        self.time_budget = time_budget
        self._cache_size = cache_size
        self.propagation = propagation if propagation is not None else Propagation()
        self._independent: set[Edge] = set(independent)
        self._evidence: dict[Edge, float] = {}
        self._latest: dict[Key, Observation] = {}
        self._failed_keys: set[Key] = set()
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
        self.structure = st = TopicStructure(model)
        th = Theory()
        self.theory = th
        self._depends: dict[Edge, int] = {}
        self._slot: dict[Key, int] = {}
        self._seen_failed: dict[Key, int] = {}
        for t in model.topics:
            self._rate_clause(th.var(("live", t)), st.producers(t, (), rate=True))
            self._value_clause(th.var(("right", t)), st.producers(t, (), rate=False))
        mentions: dict[str, list[ObservationSpec]] = {}
        for spec in model.observations:
            ok = th.var(("ok", spec.key()))
            self._slot[spec.key()] = ok
            ex = st.explain(spec)
            if not ex.components and not ex.inputs:
                ex = Explanation(tuple(t for t in (spec.resource.topic, spec.resource.topic_b)
                                       if t), ())
            if is_rate_type(spec.type):
                self._rate_clause(ok, ex)
            else:
                self._value_clause(ok, ex)
            for t in st.mentions(spec):
                mentions.setdefault(t, []).append(spec)
        for t, specs in mentions.items():
            rate = [s for s in specs if is_rate_type(s.type)]
            value = [s for s in specs if not is_rate_type(s.type)]
            self._exonerate(th.var(("live", t)), rate)
            self._exonerate(th.var(("right", t)), value)
        self._carries_nothing(mentions)
        self._watch, self._silencing = self._learning_evidence(mentions)
        self._depends_facts: list[int] | None = None
        self._literals = {k: self._literals_of(k, observation_fact(o.code))
                          for k, o in self._latest.items()}
        self.checker = ConsistencyChecker(th, model.components)
        self._conflicts: dict[frozenset[str], frozenset[int]] = {}
        self._cache: OrderedDict[frozenset[int], tuple[tuple[frozenset[str], ...], bool]] = (
            OrderedDict())
        self._facts_key: frozenset[int] | None = None
        self._upstream: dict[str, Explanation] = {}
        self._explained: dict[Key, Explanation] = {}
        self._judged: frozenset[tuple[str, bool]] | None = None

    def _silenced(self, edge: Edge) -> int:
        """A helper literal: the edge's input is not live *and* the output's rate needs it."""
        th = self.theory
        silenced = th.var(("silenced", edge))
        if edge not in self._depends:
            self._depends[edge] = th.var(("depends", edge))
            th.add([-silenced, -th.var(("live", edge.input))])
            th.add([-silenced, self._depends[edge]])
        return silenced

    def _rate_clause(self, head: int, ex: Explanation) -> None:
        """``head`` holds unless a component is abnormal or an input silences an output."""
        th = self.theory
        th.add(dict.fromkeys([head, *(th.ab(c) for c in ex.components),
                              *(self._silenced(e) for e in ex.edges)]))

    def _value_clause(self, head: int, ex: Explanation) -> None:
        """``head`` holds unless a component is abnormal or an input's values are wrong (or,
        where configured, an input is not live)."""
        th = self.theory
        stale = [-th.var(("live", e.input)) for e in ex.edges
                 if self.propagation.value_from_rate_of(e.node)]
        th.add(dict.fromkeys([head, *(th.ab(c) for c in ex.components),
                              *(-th.var(("right", i)) for i in ex.inputs), *stale]))

    def _exonerate(self, mode: int, covering: Sequence[ObservationSpec]) -> None:
        """A mode holds when all the observations judging it are OK. A mode nobody judges is
        left open (weak fault model): a rate observer says nothing about values, so it
        clears nobody of a value fault."""
        if covering:
            self.theory.add([mode, *(-self._slot[s.key()] for s in covering)])

    def _carries_nothing(self, mentions: Mapping[str, Sequence[ObservationSpec]]) -> None:
        """A topic seen silent (a failed ``timeout`` covering all its publishers, or every
        publisher failing ``activated``) carries no values, so it passes no wrong values on:
        its value mode holds. Only a failure that was reported counts (its own assumption
        literal, set only when the observation failed; NOT_AVAILABLE says nothing), and a
        stale input reaches output values through ``value_from_rate`` alone."""
        th = self.theory

        def seen_failed(spec: ObservationSpec) -> int:
            lit = self._seen_failed.get(spec.key())
            if lit is None:
                lit = self._seen_failed[spec.key()] = th.var(("seen failed", spec.key()))
            return lit

        activated = {s.resource.node: s for s in self.model.observations
                     if s.type == "activated" and s.resource.node}
        for t in self.model.topics:
            right = th.var(("right", t))
            for s in mentions.get(t, ()):
                if s.type == "timeout":
                    th.add([right, -seen_failed(s)])
            pubs = self.structure.publishers(t)
            if pubs and all(p in activated for p in pubs):
                th.add([right, *(-seen_failed(activated[p]) for p in pubs)])

    def _learning_evidence(self, mentions: Mapping[str, Sequence[ObservationSpec]]
                           ) -> tuple[dict[str, list[Watch]], dict[Key, list[str]]]:
        """Per input topic, its learnable edges with the observations that say the output
        is at rate, those that say the input is silent (time-outs) and the liveness of the
        input's publishers; and which failed observations may mean which topic is silent."""
        watch: dict[str, list[Watch]] = {}
        silencing: dict[Key, list[str]] = {}
        activated = {s.resource.node: s.key() for s in self.model.observations
                     if s.type == "activated" and s.resource.node}
        for edge in self._depends:
            if self.propagation.rate_of(edge.node) != "learn":
                continue
            at_rate = [s.key() for s in mentions.get(edge.output, ()) if is_rate_type(s.type)]
            timeouts = [s.key() for s in mentions.get(edge.input, ()) if s.type == "timeout"]
            pubs = self.structure.publishers(edge.input)
            alive = ([activated[p] for p in pubs] if pubs and all(p in activated for p in pubs)
                     else [])
            if at_rate and (timeouts or alive):
                watch.setdefault(edge.input, []).append((edge, at_rate, timeouts, alive))
                for k in (*timeouts, *alive):
                    silencing.setdefault(k, []).append(edge.input)
        return watch, silencing

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

    def _explain(self, key: Key) -> Explanation:
        ex = self._explained.get(key)
        if ex is None:
            ex = self._explained[key] = self.structure.explain(ObservationSpec(*key))
        return ex

    def _producers(self, topic: str) -> Explanation:
        ex = self._upstream.get(topic)
        if ex is None:
            ex = self._upstream[topic] = self.structure.producers(topic)
        return ex

    def closeness(self, failed: Iterable[Key]) -> dict[str, int]:
        """For every component that can explain one of the ``failed`` observations, how
        many nodes its fault must cross to reach the nearest (0: it is among that
        observation's own producers). One breadth-first walk upstream from all of them."""
        out: dict[str, int] = {}
        frontier: list[str] = []
        for key in failed:
            ex = self._explain(key)
            for c in ex.components:
                out.setdefault(c, 0)
            frontier.extend(ex.inputs)
        seen: set[str] = set()
        depth = 1
        while frontier:
            following: list[str] = []
            for topic in frontier:
                if topic in seen:
                    continue
                seen.add(topic)
                up = self._producers(topic)
                for c in up.components:
                    out.setdefault(c, depth)
                following.extend(up.inputs)
            frontier = following
            depth += 1
        return out

    def rank(self, sets: Iterable[frozenset[str]], failed: Iterable[Key] = ()
             ) -> tuple[frozenset[str], ...]:
        """Cardinality first, then the larger prior odds product, then the components
        closer to the ``failed`` observations (fewer nodes the fault must cross), then
        names. Closeness is only computed when candidates tie on the first two."""
        def odds(s: frozenset[str]) -> float:
            return round(sum(math.log(self.prior(c) / (1.0 - self.prior(c))) for c in s), 9)

        keyed = sorted(((len(s), -odds(s), sorted(s), s) for s in sets),
                       key=lambda k: k[:3])
        tied = any(a[:2] == b[:2] for a, b in itertools.pairwise(keyed))
        if not tied:
            return tuple(k[3] for k in keyed)
        near = self.closeness(failed)
        far = len(self.model.topics) + 1
        return tuple(k[3] for k in sorted(
            keyed, key=lambda k: (k[0], k[1], sum(near.get(c, far) for c in k[3]), k[2])))

    @property
    def independent(self) -> frozenset[Edge]:
        """Edges learnt not to carry silence: the node published at rate without the input."""
        return frozenset(self._independent)

    def depends(self, edge: Edge) -> bool:
        """Whether silence of ``edge.input`` is taken to silence ``edge.output``."""
        mode = self.propagation.rate_of(edge.node)
        return mode == "always" or (mode == "learn" and edge not in self._independent)

    def _facts(self) -> list[int]:
        if self._depends_facts is None:
            self._depends_facts = [v if self.depends(e) else -v
                                   for e, v in self._depends.items()]
        return sorted([*(lit for lits in self._literals.values() for lit in lits),
                       *self._depends_facts])

    def _literals_of(self, key: Key, value: bool | None) -> tuple[int, ...]:
        if value is None:
            return ()
        ok = self._slot[key]
        seen = self._seen_failed.get(key)
        return (ok if value else -ok,) if value or seen is None else (-ok, seen)

    def _learn(self, now: float) -> None:
        """Watch for a node publishing at rate while an input is silent."""
        def fact(key: Key) -> bool | None:
            obs = self._latest.get(key)
            return None if obs is None else observation_fact(obs.code)

        seen: set[Edge] = set()
        inputs = {t for k in self._failed_keys for t in self._silencing.get(k, ())}
        for topic in inputs:
            for edge, at_rate, timeouts, alive in self._watch.get(topic, ()):
                if edge in self._independent:
                    continue
                silent = (any(fact(k) is False for k in timeouts)
                          or (alive and all(fact(k) is False for k in alive)))
                if not silent or not all(fact(k) is True for k in at_rate):
                    continue
                seen.add(edge)
                since = self._evidence.setdefault(edge, now)
                if now - since >= self.propagation.learn_after:
                    self._independent.add(edge)
                    self._depends_facts = None
        self._evidence = {e: t for e, t in self._evidence.items()
                          if e in seen and e not in self._independent}

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
        out = (self.rank(res.sets, self._failed_keys), res.complete)
        if res.complete:
            self._cache[key] = out
            if len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return out

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
        """Feed new observations; a new :class:`Diagnosis` when the failed observations or the
        diagnoses changed, else ``None``."""
        # Incremental: an observation whose fact (ok / failed / no evidence) is the one
        # already held changes no literal, so it only replaces the stored observation.
        latest, literals, failed_keys = self._latest, self._literals, self._failed_keys
        changed = False
        for obs in observations:
            key = obs.key()
            prev = latest.get(key)
            value = observation_fact(obs.code)
            if prev is not None:
                latest[key] = obs
                if observation_fact(prev.code) is value:
                    continue
            elif key not in self._slot:
                self._ensure_slot(obs)  # rebuilds the model and every literal
                latest, literals = self._latest, self._literals
                latest[key] = obs
            else:
                latest[key] = obs
            changed = True
            literals[key] = self._literals_of(key, value)
            if value is False:
                failed_keys.add(key)
            else:
                failed_keys.discard(key)
        self._learn(now)
        if not changed and self._depends_facts is not None and self._facts_key is not None:
            return None  # same facts as last time
        facts = self._facts()
        fkey = frozenset(facts)
        if fkey == self._facts_key:
            return None
        self._facts_key = fkey
        failed = tuple(sorted((latest[k] for k in self._failed_keys),
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
        healthy = sum(1 for o in self._latest.values() if observation_fact(o.code) is True)
        agrees = f" and agrees with the {healthy} healthy ones" if healthy else ""
        same = [c for c in candidates[1:] if len(c) == len(best)]
        larger = [c for c in candidates[1:] if len(c) > len(best)]
        if same:
            first = self._set_words(best)
            text += (f"The observations do not tell {first} apart from {len(same)} other "
                     f"explanation{'s' if len(same) > 1 else ''} of the same size "
                     f"({self._listing(same)}); {first} {'ranks' if len(best) == 1 else 'rank'}"
                     f" first by prior fault probability and closeness to the failed "
                     f"observations. Each explains every failed observation{agrees}. ")
        else:
            text += (f"Most likely {self._set_words(best)} {verb} faulty, which explains "
                     f"every failed observation{agrees}. ")
        unjudged = self._unjudged(failed) if len(candidates) > 1 else []
        if unjudged:
            parts = []
            for mode in ("rate", "values"):
                topics = [t for t, m in unjudged if m == mode]
                if topics:
                    more = f" and {len(topics) - 4} more" if len(topics) > 4 else ""
                    parts.append(f"the {mode} of {', '.join(topics[:4])}{more}")
            text += (f"Nothing observes {' or '.join(parts)}, so faults upstream of them stay "
                     f"suspects. ")
        if larger:
            text += f"Larger minimal explanations: {self._listing(larger)}. "
        if not complete:
            text += ("The search stopped at its time budget, so other explanations may "
                     "exist.")
        elif not same:
            text += "No other explanation of the same or smaller size exists."
        return text.strip()

    def _unjudged(self, failed: Sequence[Observation]) -> list[tuple[str, str]]:
        """Upstream topics of the failed observations whose failure mode nobody judges:
        ``(topic, "rate" | "values")``, what an observer could add to narrow the list. The
        walk stops at topics whose mode is judged."""
        judged = self._judged
        if judged is None:
            judged = self._judged = frozenset(
                (t, is_rate_type(s.type)) for s in self.model.observations
                for t in self.structure.mentions(s))
        out: list[tuple[str, str]] = []
        for rate in (True, False):
            frontier = [i for o in failed if is_rate_type(o.observer) == rate
                        for i in self._explain(o.key()).inputs]
            seen: set[str] = set()
            while frontier:
                t = frontier.pop()
                if t in seen or (t, rate) in judged:
                    continue
                seen.add(t)
                out.append((t, "rate" if rate else "values"))
                frontier.extend(self._producers(t).inputs)
        return sorted(out)

    def _listing(self, sets: Sequence[frozenset[str]], shown: int = 3) -> str:
        words = "; ".join(self._set_words(c) for c in sets[:shown])
        return words + (f" (and {len(sets) - shown} more)" if len(sets) > shown else "")
