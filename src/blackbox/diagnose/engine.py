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

Re-diagnosis is incremental, so that its cost follows what changed rather than the size of
the model: the assignment is one array indexed by variable, written only for observations
whose fact changed; learning re-examines only the edges those observations watch; and a
failed observation whose clause names components alone (``activated``, ``resources``,
``network``, a rate observation of a source topic) is a conflict by itself, handed to the
HS-DAG without asking the solver. None of this changes the result: the minimal diagnoses are
those of the same clauses and assumptions, whatever sound conflicts the search starts from
(``tests/test_diagnose_incremental.py`` compares with engines built from scratch).
"""

from __future__ import annotations

import itertools
import math
import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

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
    exonerates,
    is_rate_type,
    is_relation_type,
    judges_alive,
    load_robot_model,
    shows_silent,
)
from blackbox.diagnose.sat import ConsistencyChecker, Theory
from blackbox.events import GraphSnapshot
from blackbox.model import Code, Diagnosis, Observation, Resource
from blackbox.observe.base import EVIDENCE, JudgedSignals, Subject

DEFAULT_PRIORS = {"node": 0.05, "hardware": 0.05, "topic": 0.01, "interface": 0.01}
"""Prior fault probability per component kind: with equal cardinality, a dead node is blamed
before the topic it publishes (the transport rarely fails on its own)."""

Key = tuple[str, Resource]
Watch = tuple[Edge, list[int], list[int], list[int]]
"""A learnable edge with the rows of the observations saying its output is at rate, its input
timed out, and its input's publishers are alive."""
Support = tuple[int, ...] | tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]
"""The literals a conflict rests on: a few as they are, many as arrays of their variables and
literals (one vectorised comparison with the assignment)."""
SMALL = 16
"""Up to this many items, plain Python beats a round of numpy calls."""


def observation_fact(code: Code) -> bool | None:
    """``True`` for OK, ``False`` for a failure, ``None`` for no evidence (NOT_AVAILABLE)."""
    fact = _FACT_OF.get(code, _UNKNOWN)
    if fact is not _UNKNOWN:
        return fact  # type: ignore[return-value]
    if code == Code.NOT_AVAILABLE:
        return None
    return code >= 0


_UNKNOWN = object()

VALUE_HOP_PRIOR = 0.02
"""The prior chance that a wrong input value makes a node's output values wrong, one node
crossed (``rank``): below a node's own fault prior, so two faulty producers rank before one
node upstream of both whose wrong values would have to cross a node to reach them."""

BUDGET_CLOCK = time.thread_time
"""The clock of ``time_budget``: the diagnosing thread's CPU time, not wall time, so a search
that other processes keep off the CPU is not cut short, and a replay diagnoses alike on a quiet
and on a loaded machine (a wall-clock budget cost one diagnosis of 17 in a loaded CI run)."""

_SIGN: dict[bool | None, int] = {True: 1, False: -1, None: 0}
_FACT_OF: dict[object, bool | None] = {c: None if c == Code.NOT_AVAILABLE else c >= 0
                                        for c in Code}


class DiagnosisEngine:
    """Minimal diagnoses of a :class:`RobotModel` under changing observations.

    ``priors`` maps component names (or kinds: ``node``, ``hardware``, ``topic``,
    ``interface``) to prior fault probabilities in (0, 1). ``max_cardinality`` bounds the
    size of a diagnosis, ``time_budget`` (seconds of this thread's CPU, :data:`BUDGET_CLOCK`)
    the search of one re-diagnosis.
    ``propagation`` says how input faults reach a node's outputs; ``independent`` are edges
    already learnt not to carry silence and ``blamed`` the components of the first candidate
    so far (an engine rebuilt for a changed graph keeps both).
    """

    def __init__(self, model: RobotModel, priors: Mapping[str, float] | None = None, *,
                 max_cardinality: int | None = None, time_budget: float = 0.1,
                 cache_size: int = 256, propagation: Propagation | None = None,
                 independent: Iterable[Edge] = (),
                 signals: Mapping[Key, JudgedSignals] | None = None,
                 blamed: Iterable[str] = ()) -> None:
        self.priors = dict(priors or {})
        self._blamed = frozenset(blamed)
        for name, p in self.priors.items():
            if not 0.0 < p < 1.0:
                raise ValueError(f"prior of {name!r} must be in (0, 1), got {p}")
        self.max_cardinality = max_cardinality
        self.time_budget = time_budget
        self._cache_size = cache_size
        self.propagation = propagation if propagation is not None else Propagation()
        self._independent: set[Edge] = set(independent)
        self._signals: dict[Key, JudgedSignals] = dict(signals or {})
        self._evidence: dict[Edge, float] = {}
        self._current = Diagnosis(time=0.0, candidates=(), explanation="No observations yet.")
        self._emitted_rows: list[int] = []
        self._build(model, {})

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

    def _build(self, model: RobotModel, latest: Mapping[Key, Observation]) -> None:
        """Encode ``model``; ``latest`` are the observations held so far (all in the model)."""
        self.model = model
        self.structure = st = TopicStructure(model)
        th = Theory()
        self.theory = th
        self._depends: dict[Edge, int] = {}
        self._slot: dict[Key, int] = {}
        self._seen_failed: dict[Key, int] = {}
        self._upstream_of: dict[str, frozenset[str]] = {}
        self._upstream: dict[str, Explanation] = {}
        for t in model.topics:
            self._rate_clause(th.var(("live", t)), st.producers(t, (), rate=True))
            self._value_clause(th.var(("right", t)), st.producers(t, (), rate=False))
        mentions: dict[str, list[ObservationSpec]] = {}
        direct: dict[Key, frozenset[str]] = {}
        diagnosable = set(model.components)
        # Per topic, literals true while a check of its signals' aliveness is seen failed: a
        # relation of the topic failing meanwhile may be that burst or freeze (held
        # relations clear offsets, not those), so the two failures share one explanation.
        # The shared-upstream rule still holds: a burst upstream of both sides reaches both.
        not_alive: dict[str, list[int]] = {}
        for spec in model.observations:
            if judges_alive(spec.type) and spec.resource.topic:
                not_alive.setdefault(spec.resource.topic, []).append(
                    self._seen_failed_var(spec.key()))
        for spec in model.observations:
            ok = th.var(("ok", spec.key()))
            self._slot[spec.key()] = ok
            ex = st.explain(spec)
            if not ex.components and not ex.inputs:
                ex = Explanation(tuple(t for t in (spec.resource.topic, spec.resource.topic_b)
                                       if t), ())
            if is_relation_type(spec.type):
                # Failed: the values of one of its signals (fields, when the observer says
                # which, else its topics) are wrong. Held: each it clears is right (faults
                # that cancel out exactly are not assumed).
                # A fault upstream of every topic of the relation moves them all alike: seen
                # failed, it needs a wrong value outside their shared upstream topics (its
                # own literal, so a relation not judged constrains nothing).
                judged = self._signals.get(spec.key())
                common = self._common_upstream(spec)
                if judged is None:
                    topics = [t for t in (spec.resource.topic, spec.resource.topic_b) if t]
                    dying = [lit for t in dict.fromkeys(topics) for lit in not_alive.get(t, ())]
                    th.add([ok, *(-th.var(("right", t)) for t in topics), *dying])
                    for t in topics:
                        th.add([th.var(("right", t)), -ok])
                    if common:
                        th.add([-self._seen_failed_var(spec.key()),
                                *(-self._right_var(t, common) for t in topics)])
                    continue
                dying = [lit for t in dict.fromkeys(t for t, _ in judged.accused)
                         for lit in not_alive.get(t, ())]
                th.add([ok, *(-self._signal_var(t, f) for t, f in judged.accused), *dying])
                for t, f in judged.cleared:
                    th.add([self._signal_var(t, f), -ok])
                if common:
                    th.add([-self._seen_failed_var(spec.key()),
                            *(-self._signal_var(t, f, common) for t, f in judged.accused)])
                continue
            if (ex.components and not ex.inputs and not ex.edges
                    and diagnosable.issuperset(ex.components)):
                # The clause is "ok or one of these is abnormal": failed, it is a conflict.
                direct[spec.key()] = frozenset(ex.components)
            if is_rate_type(spec.type):
                self._rate_clause(ok, ex)
            else:
                self._value_clause(ok, ex)
            for t in st.mentions(spec):
                mentions.setdefault(t, []).append(spec)
        for t, specs in mentions.items():
            rate = [s for s in specs if is_rate_type(s.type)]
            # A passing envelope is no proof of right values: only types that see every
            # fault of the mode clear it (docs/diagnosis.md, issue 22 item 8).
            value = [s for s in specs if not is_rate_type(s.type) and exonerates(s.type)]
            self._exonerate(th.var(("live", t)), rate)
            self._exonerate(th.var(("right", t)), value)
        self._carries_nothing(mentions)
        # Every observation has a row; per-observation state is kept in lists by row, so an
        # update hashes each observation's key once.
        emitted = [self._keys[i] for i in self._emitted_rows] if self._emitted_rows else []
        self._keys: list[Key] = list(self._slot)
        self._row: dict[Key, int] = {k: i for i, k in enumerate(self._keys)}
        self._emitted_rows = [self._row[k] for k in emitted]  # rows of the last failed list
        self._obs: list[Observation | None] = [latest.get(k) for k in self._keys]
        self._held = len(self._obs) - self._obs.count(None)
        self._by_resource: dict[int, tuple[Resource, dict[str, int]]] = {}
        self._direct: dict[int, frozenset[str]] = {self._row[k]: c for k, c in direct.items()}
        self._watch = self._learning_evidence(mentions)
        # Rows whose turning OK (``_at_rate_watchers``) or failed (``_silence_watchers``) may
        # start evidence for an edge.
        self._at_rate_watchers: dict[int, list[Watch]] = {}
        self._silence_watchers: dict[int, list[Watch]] = {}
        # The same as arrays of (row, watch, its first at-rate row, 1 turning OK / -1 turning
        # failed starts evidence), to find the edges a large change may start in one go.
        pairs: list[tuple[int, int, int, int]] = []
        for wi, w in enumerate(self._watch):
            for i in w[1]:
                self._at_rate_watchers.setdefault(i, []).append(w)
                pairs.append((i, wi, w[1][0], 1))
            for i in dict.fromkeys((*w[2], *w[3])):
                self._silence_watchers.setdefault(i, []).append(w)
                pairs.append((i, wi, w[1][0], -1))
        self._pairs = np.array(pairs, dtype=np.int64).reshape(-1, 4).T.copy()
        self.checker = ConsistencyChecker(th, model.components)
        self._negated = np.zeros(th.num_vars + 1, dtype=bool)  # variables some clause negates
        self._negated[[-lit for clause in th.clauses for lit in clause if lit < 0]] = True
        self._conflicts: dict[frozenset[str], Support] = {}
        self._cache: OrderedDict[bytes, tuple[tuple[frozenset[str], ...], bool]] = (
            OrderedDict())
        self._facts_key: bytes | None = None
        self._explained: dict[Key, Explanation] = {}
        self._judged: frozenset[tuple[str, bool]] | None = None
        self._kinds: dict[str, str] = {}
        for n in model.nodes:  # first match wins, as in RobotModel.kind
            self._kinds.setdefault(n.name, "node")
            for h in n.hardware:
                self._kinds.setdefault(h, "hardware")
        labels = [(k[0], k[1].label()) for k in self._keys]
        position = {label: i for i, label in enumerate(sorted(set(labels)))}
        self._order = [position[label] for label in labels]  # the failed list's order
        self._order_array = np.array(self._order, dtype=np.int64)
        # The assignment: ``_assign[v]`` is the assumption literal of variable v, 0 for none.
        # Per row, the ``ok`` and ``seen failed`` variables (0: none; 0 is never a variable).
        self._assign: npt.NDArray[np.int64] = np.zeros(th.num_vars + 1, dtype=np.int64)
        self._ok_var = np.array([self._slot[k] for k in self._keys], dtype=np.int64)
        self._seen_var = np.array([self._seen_failed.get(k, 0) for k in self._keys],
                                  dtype=np.int64)
        self._fact: list[bool | None] = [None] * len(self._keys)
        self._failed: set[int] = set()
        seen = self._seen_var[self._seen_var > 0]
        self._assign[seen] = -seen  # not seen failed until an observation fails
        self._set_facts({i: observation_fact(o.code) for i, o in enumerate(self._obs)
                         if o is not None})
        self._write_depends()
        self._evidencing: dict[Edge, Watch] = {w[0]: w for w in self._watch
                                               if self._evidences(w)}
        self.checker.warm_up()

    def _signal_var(self, topic: str, field: str, common: frozenset[str] = frozenset()
                    ) -> int:
        """``right(topic, field)``: the values of one field are right. It holds when the
        topic's values are right, and else, as the topic's value mode, unless a producer is
        abnormal or an input's values are wrong: a fault of the field is a fault of the
        topic's producers, but a relation held on one field clears no other field.

        With ``common`` (the upstream topics every topic of a relation shares), the field's
        mode for that relation: it holds when the field is right, and else as above with the
        ``common`` topics taken as right."""
        th = self.theory
        key = ("right signal", topic, field, common) if common else ("right signal", topic, field)
        known = th.num_vars
        var = th.var(key)
        if th.num_vars > known:
            if common:
                th.add([var, -self._signal_var(topic, field)])
            else:
                th.add([var, -th.var(("right", topic))])
            self._value_clause(var, self.structure.producers(topic, (), rate=False), common)
        return var

    def _seen_failed_var(self, key: Key) -> int:
        """A literal true exactly while the observation ``key`` is failed (assumed false
        otherwise, unobserved included)."""
        lit = self._seen_failed.get(key)
        if lit is None:
            lit = self._seen_failed[key] = self.theory.var(("seen failed", key))
        return lit

    def _right_var(self, topic: str, common: frozenset[str] = frozenset()) -> int:
        """``right(topic)``, or with ``common`` its mode for a relation whose topics all
        share those upstream topics (holds when ``right(topic)`` does, and else unless a
        producer is abnormal or an input outside ``common`` is wrong for it)."""
        th = self.theory
        if not common:
            return th.var(("right", topic))
        known = th.num_vars
        var = th.var(("right", topic, common))
        if th.num_vars > known:
            th.add([var, -th.var(("right", topic))])
            self._value_clause(var, self.structure.producers(topic, (), rate=False), common)
        return var

    def _upstream_topics(self, topic: str) -> frozenset[str]:
        """The topics whose wrong values can reach ``topic``'s through its producers (inputs
        from outside its feedback loop, transitively)."""
        known = self._upstream_of.get(topic)
        if known is not None:
            return known
        out: set[str] = set()
        frontier = list(self._producers(topic).inputs)
        while frontier:
            t = frontier.pop()
            if t not in out:
                out.add(t)
                frontier.extend(self._producers(t).inputs)
        found = self._upstream_of[topic] = frozenset(out)
        return found

    def _common_upstream(self, spec: ObservationSpec) -> frozenset[str]:
        """The upstream topics every topic of a relation over two or more topics shares,
        less those topics: a wrong value there reaches all of its signals alike (a command
        the wheels, the odometry computed from them and the IMU on the moving robot all
        follow), so it cannot make them disagree (docs/diagnosis.md, "relation")."""
        topics = list(dict.fromkeys(t for t in (spec.resource.topic, spec.resource.topic_b)
                                    if t))
        if len(topics) < 2:
            return frozenset()
        shared = frozenset.intersection(*(self._upstream_topics(t) for t in topics))
        return shared - set(topics)

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

    def _value_clause(self, head: int, ex: Explanation,
                      common: frozenset[str] = frozenset()) -> None:
        """``head`` holds unless a component is abnormal or an input's values are wrong (or,
        where configured, an input is not live); inputs in ``common`` are taken as right,
        the others in their mode for ``common`` (:meth:`_right_var`)."""
        th = self.theory
        stale = [-th.var(("live", e.input)) for e in ex.edges
                 if self.propagation.value_from_rate_of(e.node)]
        th.add(dict.fromkeys([head, *(th.ab(c) for c in ex.components),
                              *(-self._right_var(i, common) for i in ex.inputs
                                if i not in common), *stale]))

    def _exonerate(self, mode: int, covering: Sequence[ObservationSpec]) -> None:
        """A mode holds when all the observations judging it are OK. A mode nobody judges is
        left open (weak fault model): a rate observer says nothing about values, so it
        clears nobody of a value fault."""
        if covering:
            self.theory.add([mode, *(-self._slot[s.key()] for s in covering)])

    def _carries_nothing(self, mentions: Mapping[str, Sequence[ObservationSpec]]) -> None:
        """A topic seen silent (a failed ``timeout`` covering all its publishers, or every
        publisher failing ``activated``: the types registered ``failure_means_silent``)
        carries no values, so it passes no wrong values on: its value mode holds. Only a
        failure that was reported counts (its own assumption literal, set only when the
        observation failed; NOT_AVAILABLE says nothing), and a stale input reaches output
        values through ``value_from_rate`` alone."""
        th = self.theory

        def seen_failed(spec: ObservationSpec) -> int:
            return self._seen_failed_var(spec.key())

        activated = {s.resource.node: s for s in self.model.observations
                     if shows_silent(s.type) is Subject.NODE and s.resource.node}
        for t in self.model.topics:
            right = th.var(("right", t))
            for s in mentions.get(t, ()):
                if shows_silent(s.type) is Subject.TOPIC:
                    th.add([right, -seen_failed(s)])
            pubs = self.structure.publishers(t)
            if pubs and all(p in activated for p in pubs):
                th.add([right, *(-seen_failed(activated[p]) for p in pubs)])

    def _learning_evidence(self, mentions: Mapping[str, Sequence[ObservationSpec]]
                           ) -> list[Watch]:
        """The learnable edges with the observations that say the output is at rate, those
        that say the input is silent (time-outs) and the liveness of the input's
        publishers."""
        watch: list[Watch] = []
        row = self._row
        activated = {s.resource.node: row[s.key()] for s in self.model.observations
                     if shows_silent(s.type) is Subject.NODE and s.resource.node}
        for edge in self._depends:
            if self.propagation.rate_of(edge.node) != "learn":
                continue
            at_rate = [row[s.key()] for s in mentions.get(edge.output, ())
                       if is_rate_type(s.type)]
            timeouts = [row[s.key()] for s in mentions.get(edge.input, ())
                        if shows_silent(s.type) is Subject.TOPIC]
            pubs = self.structure.publishers(edge.input)
            alive = ([activated[p] for p in pubs] if pubs and all(p in activated for p in pubs)
                     else [])
            if at_rate and (timeouts or alive):
                watch.append((edge, at_rate, timeouts, alive))
        return watch

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
        self._build(build_model([*self.model.nodes, *extra], [*self.model.observations, spec]),
                    self._latest)

    # ---- diagnosis ---------------------------------------------------------------------------

    def prior(self, component: str) -> float:
        p = self.priors.get(component)
        if p is None:
            kind = self._kind(component)
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

    def _cleared_now(self) -> frozenset[tuple[str, str]]:
        """The (topic, field) signals that relation observations passing now clear."""
        out: set[tuple[str, str]] = set()
        for key, obs in zip(self._keys, self._obs, strict=True):
            judged = self._signals.get(key)
            if judged is not None and obs is not None and observation_fact(obs.code) is True:
                out.update(judged.cleared)
        return frozenset(out)

    def _own_producers(self, key: Key,
                       cleared: frozenset[tuple[str, str]] = frozenset()) -> frozenset[str]:
        """The observed topics themselves, their publishers and those publishers' hardware:
        in a feedback loop (a command and the odometry it is computed from) every node of
        the loop explains the observation, but the publisher of the observed topic is
        closer to it than the node across the loop (ranking only; the diagnoses are the
        same). A failed relation's topic whose every signal in it a passing relation
        clears (``cleared``) is not its own: its publisher explains the failure only through
        the other topic, across the node that reads it (the wheel speeds a held IMU relation
        vouches for, when a relation of the command and the wheels fails: the command's
        publisher reads the wheels, so the wheels' publisher explains a wrong command as
        well, one node away; issue 22, round learn7)."""
        r = key[1]
        out: set[str] = set()
        if r.node:
            out.add(r.node)
        if r.interface:
            out.add(f"iface:{r.interface}")
        topics = [t for t in (r.topic, r.topic_b) if t]
        judged = self._signals.get(key)
        if judged is not None and cleared:
            open_topics = {t for t, f in judged.accused if (t, f) not in cleared}
            if open_topics:
                topics = [t for t in topics if t in open_topics]
        for t in topics:
            if not t:
                continue
            out.add(t)
            for p in self.structure.publishers(t):
                out.add(p)
                spec = self.structure.model.node(p)
                if spec is not None:
                    out.update(spec.hardware)
        return frozenset(out)

    def closeness(self, failed: Iterable[Key],
                  cleared: frozenset[tuple[str, str]] | None = None) -> dict[str, int]:
        """For every component that can explain one of the ``failed`` observations, how
        many nodes its fault must cross to reach the nearest (0: it is among that
        observation's own producers, less those of a topic whose signals in a failed
        relation passing relations all clear: ``cleared``, by default the signals cleared
        now). One breadth-first walk upstream from all of them."""
        out: dict[str, int] = {}
        frontier: list[str] = []
        if cleared is None:
            cleared = self._cleared_now()
        for key in failed:
            ex = self._explain(key)
            own = self._own_producers(key, cleared)
            for c in ex.components:
                out[c] = min(out.get(c, 1), 0 if c in own else 1)
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
        """The likelier first: the larger product of the components' prior odds and of
        :data:`VALUE_HOP_PRIOR`'s odds for every node a wrong value must cross to reach a
        failed value observation (:meth:`value_hops`), or, if likelier, of the prior odds of
        the candidate with the producers of those observations added (a wheel driver alone
        explains a wrong odometry through the odometry node, but a wrong odometry node
        beside it is likelier than that crossing: the driver then ranks as the pair, before
        another pair that needs a crossing), then cardinality (of the candidate so
        completed), then the components
        closer to the ``failed`` observations (fewer nodes the fault must cross, summed
        over the failed observations: the producer of the one topic two failed relations
        share is closer than a node upstream of one of them), then the more components of
        the first candidate so far (:attr:`blamed`: a fault persists, so a new failure two
        candidates explain alike is likelier a new fault than the old one moving), then the
        more evidence short of an alarm against the candidate (``_pending_evidence``), then the
        fewer passing observations that involve the candidate (a command that four relations
        and its liveness currently pass is less suspect than a sensor only one passes), then
        names.
        The closeness of failed value observations is computed for any two candidates;
        that of the others, and passing, only when candidates tie on the first two."""
        sets = list(sets)
        keys = list(dict.fromkeys(failed))
        cleared = self._cleared_now() if len(sets) > 1 else frozenset()
        nears = ({key: self.closeness((key,), cleared) for key in keys
                  if not is_rate_type(key[0])} if len(sets) > 1 else {})
        paths = self._value_paths(sets, list(nears.values()))
        hop = math.log(VALUE_HOP_PRIOR / (1.0 - VALUE_HOP_PRIOR))

        def log_odds(s: Iterable[str]) -> float:
            return sum(math.log(self.prior(c) / (1.0 - self.prior(c))) for c in s)

        def odds(s: frozenset[str]) -> tuple[float, int]:
            """Log odds and size of the likelier of its wrong values crossing nodes and
            its members with those producers faulty too (which, a superset, is no minimal
            diagnosis itself)."""
            hops, direct = paths.get(s, (0, frozenset()))
            crossing = round(log_odds(s) + hop * hops, 9)
            if not hops:
                return crossing, len(s)
            both = round(log_odds(s | direct), 9)
            return (both, len(s | direct)) if both > crossing else (crossing, len(s))

        keyed = sorted(((-o, n, sorted(s), s) for s in sets for o, n in [odds(s)]),
                       key=lambda k: k[:3])
        tied = any(a[:2] == b[:2] for a, b in itertools.pairwise(keyed))
        if not tied:
            return tuple(k[3] for k in keyed)
        far = len(self.model.topics) + 1
        closeness = [nears[key] if key in nears else self.closeness((key,), cleared)
                     for key in keys]

        def distance(s: frozenset[str]) -> int:
            return sum(min(near.get(c, far) for near in closeness) if closeness else 0
                       for c in s) + sum(min(near.get(c, far) for c in s) for near in closeness)

        passing: dict[str, int] = {}
        for key, obs in zip(self._keys, self._obs, strict=True):
            if obs is not None and obs.code >= 0:
                for c in self._explain(key).components:
                    passing[c] = passing.get(c, 0) + 1

        def vouched(s: frozenset[str]) -> int:
            return sum(passing.get(c, 0) for c in s)

        pending = self._pending_evidence()

        def suspected(s: frozenset[str]) -> float:
            return -round(sum(pending.get(c, 0.0) for c in s), 6)

        def kept(s: frozenset[str]) -> int:
            return -len(s & self._blamed)

        return tuple(k[3] for k in sorted(
            keyed, key=lambda k: (k[0], k[1], distance(k[3]), kept(k[3]), suspected(k[3]),
                                  vouched(k[3]), k[2])))

    def value_hops(self, sets: Sequence[frozenset[str]], failed: Iterable[Key]
                   ) -> dict[frozenset[str], int]:
        """Per candidate, the nodes wrong values must cross from it to the failed value
        observations, summed over them (each from its nearest component; 0 for one it
        produces). A single node upstream of two faulty sensors explains both through the
        graph, but that a wrong input makes a node's output wrong is itself unlikely: the
        real and simulated robots' nodes compute from their own measurements, and a node
        that does compute from its input moves the relations of both alike (issue 22:
        ``/teleop`` or ``/base_driver`` alone outranked the two faulty sensors by
        cardinality)."""
        cleared = self._cleared_now()
        nears = [self.closeness((key,), cleared) for key in dict.fromkeys(failed)
                 if not is_rate_type(key[0])]
        return {s: hops for s, (hops, _) in self._value_paths(sets, nears).items()}

    def _value_paths(self, sets: Sequence[frozenset[str]], nears: Sequence[Mapping[str, int]]
                     ) -> dict[frozenset[str], tuple[int, frozenset[str]]]:
        """Per candidate, :meth:`value_hops` over the failed value observations' closeness
        (``nears``) and the producers that would explain the observations it reaches only
        across nodes directly (a greedy cover by the observations' own producers)."""
        if not nears:
            return {}
        out: dict[frozenset[str], tuple[int, frozenset[str]]] = {}
        for s in sets:
            total = 0
            far: list[frozenset[str]] = []
            for near in nears:
                reach = [near[c] for c in s if c in near]
                hop = min(reach) if reach else 0
                total += hop
                if hop:
                    far.append(frozenset(c for c, d in near.items() if d == 0))
            extra: set[str] = set()
            while far:
                counts: dict[str, int] = {}
                for own in far:
                    for c in own:
                        counts[c] = counts.get(c, 0) + 1
                if not counts:
                    break
                best = min(counts, key=lambda c: (-counts[c], -self.prior(c), c))
                extra.add(best)
                far = [own for own in far if best not in own]
            out[s] = (total, frozenset(extra))
        return out

    def _pending_evidence(self) -> dict[str, float]:
        """Per component, the mean evidence short of an alarm (a sequential test's
        statistic over its threshold, the largest of an observation's values ending in
        ``EVIDENCE``) over the observations that have not failed and that it explains. A
        fault on a command that one relation caught moves the command's other relations
        too, only more slowly, while a fault on a sensor moves only the relations of that
        sensor: among candidates that explain the failures equally well, the one whose other
        relations are building evidence is the likelier (issue 22: offsets and scales of a
        commanded yaw rate, caught by the IMU relation alone, were blamed on the IMU). The
        mean, not the largest: a command related to every sensor would otherwise take the
        evidence of any other fault as its own."""
        levels: dict[str, list[float]] = {}
        for key, obs in zip(self._keys, self._obs, strict=True):
            if obs is None or observation_fact(obs.code) is False:
                continue
            evidence = [v for name, v in obs.values.items() if name.endswith(EVIDENCE)]
            if not evidence:
                continue
            for c in self._explain(key).components:
                levels.setdefault(c, []).append(max(evidence))
        return {c: sum(ls) / len(ls) for c, ls in levels.items()}

    @property
    def blamed(self) -> frozenset[str]:
        """The components of the first candidate of the latest diagnosis (ranking prefers
        them among candidates that explain a new failure alike)."""
        return self._blamed

    @property
    def independent(self) -> frozenset[Edge]:
        """Edges learnt not to carry silence: the node published at rate without the input."""
        return frozenset(self._independent)

    def depends(self, edge: Edge) -> bool:
        """Whether silence of ``edge.input`` is taken to silence ``edge.output``."""
        mode = self.propagation.rate_of(edge.node)
        return mode == "always" or (mode == "learn" and edge not in self._independent)

    def _facts(self) -> npt.NDArray[np.int64]:
        """The assumption literals of the current assignment, in ascending order, without
        the positive literals of variables no clause negates (an OK ``activated``, a
        ``depends`` edge): such a literal only satisfies clauses, so it changes neither
        whether the solver finds a model nor any conflict (pure literal rule), and leaving
        out a third of the assumptions makes every check cheaper."""
        assign = self._assign
        lits: npt.NDArray[np.int64] = assign[(assign < 0) | ((assign > 0) & self._negated)]
        lits.sort()
        return lits

    @property
    def _latest(self) -> dict[Key, Observation]:
        """The latest observation per key."""
        return {k: o for k, o in zip(self._keys, self._obs, strict=True) if o is not None}

    def _failed_rows(self) -> list[int]:
        """Rows of the failed observations, in the order of the failed list."""
        if len(self._failed) <= SMALL:
            return sorted(self._failed, key=self._order.__getitem__)
        failed = np.fromiter(self._failed, dtype=np.int64, count=len(self._failed))
        rows: list[int] = failed[np.argsort(self._order_array[failed], kind="stable")].tolist()
        return rows

    def _row_of(self, obs: Observation) -> int:
        """The row of ``obs``'s key, extending the model for an undeclared one; remembered
        per resource object, so the next observation of it needs no hashing of its key."""
        r = obs.resource
        i = self._row.get((obs.observer, r))
        if i is None:
            self._old_keys = self._keys
            self._ensure_slot(obs)  # rebuilds the model and the whole assignment
            i = self._row[(obs.observer, r)]
        if len(self._by_resource) > 2 * len(self._keys) + 64:
            self._by_resource.clear()  # resources made afresh per observation: start over
        seen = self._by_resource.get(id(r))
        if seen is None or seen[0] is not r:
            # The entry holds ``r``, so no other object can have its id while it is there.
            seen = self._by_resource[id(r)] = (r, {})
        seen[1][obs.observer] = i
        return i

    def _set_facts(self, facts: Mapping[int, bool | None]) -> None:
        """Record new facts (by row) and write their literals into the assignment."""
        fact, failed = self._fact, self._failed
        rows = list(facts)
        values = list(facts.values())
        for i, value in zip(rows, values, strict=True):
            fact[i] = value
        now_failed = [i for i, value in zip(rows, values, strict=True) if value is False]
        failed.difference_update(rows)
        failed.update(now_failed)
        for i in self._direct.keys() & now_failed:
            self._conflicts[self._direct[i]] = (-self._ok_var.item(i),)
        assign = self._assign
        if len(rows) <= SMALL:
            for i, value in zip(rows, values, strict=True):
                sg = _SIGN[value]
                ok, seen = self._ok_var.item(i), self._seen_var.item(i)
                assign[ok] = ok * sg
                if seen:
                    assign[seen] = seen if sg < 0 else -seen
            return
        at = np.array(rows, dtype=np.int64)
        sign = np.fromiter(map(_SIGN.__getitem__, values), dtype=np.int64, count=len(rows))
        ok_vars = self._ok_var[at]
        self._assign[ok_vars] = ok_vars * sign
        seen_vars = self._seen_var[at]
        self._assign[seen_vars] = np.where(sign < 0, seen_vars, -seen_vars)
        self._assign[0] = 0

    def _write_depends(self) -> None:
        for e, v in self._depends.items():
            self._assign[v] = v if self.depends(e) else -v

    def _evidences(self, watch: Watch) -> bool:
        """Whether the watched edge's input is silent while its output is at rate."""
        _, at_rate, timeouts, alive = watch
        fact = self._fact
        for i in at_rate:
            if fact[i] is not True:
                return False
        for i in timeouts:
            if fact[i] is False:
                return True
        return bool(alive) and all(fact[i] is False for i in alive)

    def _learn(self, now: float, changed: Mapping[int, bool | None]) -> bool:
        """Watch for a node publishing at rate while an input is silent; ``changed`` are the
        rows whose fact changed. Whether an edge was learnt."""
        evidencing = self._evidencing
        if changed:
            # Evidence starts only when an at-rate observation turns OK or a silencing one
            # turns failed; it can stop on any change, so the edges with evidence are
            # looked at again.
            touched = dict(evidencing)
            if len(changed) <= SMALL:
                at_rate, silence = self._at_rate_watchers, self._silence_watchers
                fact = self._fact
                for i, value in changed.items():
                    if value is None:
                        continue
                    for w in (at_rate if value else silence).get(i, ()):
                        if fact[w[1][0]] is True:  # else its output is not at rate
                            touched[w[0]] = w
            elif self._watch:
                row, watch, first, starts = self._pairs
                turned = np.zeros(len(self._keys), dtype=np.int64)
                turned[np.fromiter(changed, dtype=np.int64, count=len(changed))] = np.fromiter(
                    map(_SIGN.__getitem__, changed.values()), dtype=np.int64, count=len(changed))
                hit = (turned[row] == starts) & (self._assign[self._ok_var[first]] > 0)
                for wi in np.unique(watch[hit]).tolist():
                    w = self._watch[wi]
                    touched[w[0]] = w
            for edge, w in touched.items():
                if self._evidences(w):
                    evidencing[edge] = w
                else:
                    evidencing.pop(edge, None)
        if not evidencing and not self._evidence:
            return False
        learnt = False
        seen: set[Edge] = set()
        for edge in evidencing:
            if edge in self._independent:
                continue
            seen.add(edge)
            since = self._evidence.setdefault(edge, now)
            if now - since >= self.propagation.learn_after:
                self._independent.add(edge)
                learnt = True
        self._evidence = {e: t for e, t in self._evidence.items()
                          if e in seen and e not in self._independent}
        if learnt:
            self._write_depends()
        return learnt

    def _holds(self, support: Support) -> bool:
        """Whether every literal of ``support`` is in the current assignment."""
        assign = self._assign
        if support and isinstance(support[0], np.ndarray):
            variables, lits = support
            return bool((assign[variables] == lits).all())
        item = assign.item
        return all(item(abs(lit)) == lit for lit in support)

    def _search(self, facts: npt.NDArray[np.int64], key: bytes, failed: Iterable[Key]
                ) -> tuple[tuple[frozenset[str], ...], bool]:
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return self.rank(hit[0], failed), hit[1]
        deadline = BUDGET_CLOCK() + self.time_budget
        reusable = [c for c, support in self._conflicts.items() if self._holds(support)]
        assumptions = facts.tolist()

        def prover(path: frozenset[str]) -> frozenset[str] | None:
            conflict = self.checker.conflict(assumptions, path, deadline, BUDGET_CLOCK)
            if conflict is None:
                return None
            lits = sorted(conflict.support)
            if len(lits) <= SMALL:
                self._conflicts[conflict.components] = tuple(lits)
            else:
                support = np.array(lits, dtype=np.int64)
                self._conflicts[conflict.components] = (np.abs(support), support)
            return conflict.components

        res = hs_dag(prover, conflicts=reusable, max_cardinality=self.max_cardinality,
                     deadline=deadline, clock=BUDGET_CLOCK)
        if res.complete:
            self._cache[key] = (res.sets, res.complete)
            if len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return self.rank(res.sets, failed), res.complete

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
        """Feed new observations; a new :class:`Diagnosis` when the failed observations or the
        diagnoses changed, else ``None``."""
        # Incremental: an observation whose fact (ok / failed / no evidence) is the one
        # already held changes no literal, so it only replaces the stored observation.
        held, fact_of = self._obs, _FACT_OF
        by_id = self._by_resource.get
        changed: dict[int, bool | None] = {}
        for obs in observations:
            r = obs.resource
            seen = by_id(id(r))
            i = seen[1].get(obs.observer) if seen is not None and seen[0] is r else None
            if i is None:
                i = self._row_of(obs)
                if held is not self._obs:  # the model was extended and rebuilt
                    changed = {self._row[self._old_keys[j]]: v for j, v in changed.items()}
                    held, by_id = self._obs, self._by_resource.get
            prev = held[i]
            held[i] = obs
            if prev is None:
                self._held += 1
            elif prev.code is obs.code:
                continue
            try:
                value = fact_of[obs.code]
            except KeyError:
                value = observation_fact(obs.code)
            if prev is not None:
                try:
                    before = fact_of[prev.code]
                except KeyError:
                    before = observation_fact(prev.code)
                if before is value:
                    continue
            changed[i] = value  # the fact held now (a row may change twice in one call)
        if changed:
            self._set_facts(changed)
        learnt = self._learn(now, changed)
        if not changed and not learnt and self._facts_key is not None:
            return None  # same facts as last time
        facts = self._facts()
        fkey = facts.tobytes()
        if fkey == self._facts_key:
            return None
        self._facts_key = fkey
        failed_rows = self._failed_rows()
        keys = self._keys
        if failed_rows:
            candidates, complete = self._search(facts, fkey, (keys[i] for i in failed_rows))
        else:
            candidates, complete = (), True
        self._blamed = candidates[0] if candidates else frozenset()
        previous = self._current
        if (candidates == previous.candidates and complete == previous.complete
                and failed_rows == self._emitted_rows and previous.time > 0.0):
            return None
        failed = tuple(o for i in failed_rows if (o := held[i]) is not None)
        clash = self.contradiction(facts) if failed and not candidates and complete else None
        self._current = Diagnosis(now, candidates, failed,
                                  self.explain(candidates, failed, complete, clash), complete)
        self._emitted_rows = failed_rows
        return self._current

    def current(self) -> Diagnosis:
        return self._current

    def contradiction(self, facts: npt.NDArray[np.int64] | None = None
                      ) -> tuple[tuple[Observation, ...], tuple[Observation, ...]] | None:
        """The failed and the passing observations that contradict each other whatever is
        faulty (a minimal set, within the time budget), or ``None`` when some assignment of
        faults explains every failure.

        When no diagnosis exists the operator must learn which observations disagree: a
        passing one clears what it sees, so a failure whose every explanation it clears is
        a fault of the model or the configuration (or of the observers), not of the robot.
        """
        lits = (self._facts() if facts is None else facts).tolist()
        deadline = BUDGET_CLOCK() + self.time_budget
        everyone = self.checker.components
        found = self.checker.conflict(lits, everyone, deadline, BUDGET_CLOCK)
        if found is None:
            return None
        core = sorted(found.support)
        i = 0
        while i < len(core) and BUDGET_CLOCK() < deadline:
            trial = self.checker.conflict(core[:i] + core[i + 1:], everyone, deadline,
                                          BUDGET_CLOCK)
            if trial is None:
                i += 1
            else:
                core = sorted(trial.support)
        # An observation's own literal says it failed or passed; its "seen failed" literal
        # counts only when it failed (an aliveness check that did not fail clears nobody).
        row_of = {ok: i for i, ok in enumerate(self._ok_var.tolist())}
        row_of.update((seen, i) for i, seen in enumerate(self._seen_var.tolist()) if seen)
        ok_vars = set(self._ok_var.tolist())
        bad: dict[int, Observation] = {}
        good: dict[int, Observation] = {}
        for lit in core:
            row = row_of.get(abs(lit))
            if row is None or (lit < 0 and abs(lit) not in ok_vars):
                continue
            if (obs := self._obs[row]) is not None:
                (good if self._fact[row] else bad)[row] = obs
        order = self._order
        return (tuple(bad[r] for r in sorted(bad, key=order.__getitem__)),
                tuple(good[r] for r in sorted(good, key=order.__getitem__)))

    # ---- words -------------------------------------------------------------------------------

    def _kind(self, component: str) -> str:
        """``RobotModel.kind`` from a table built once (the model scans its nodes)."""
        if component.startswith("iface:"):
            return "interface"
        return self._kinds.get(component, "topic")

    def _name(self, component: str) -> str:
        kind = self._kind(component)
        if kind == "interface":
            return f"network interface {component.removeprefix('iface:')}"
        return f"{kind} {component}"

    def _set_words(self, s: frozenset[str]) -> str:
        return " and ".join(self._name(c) for c in sorted(s))

    def explain(self, candidates: Sequence[frozenset[str]], failed: Sequence[Observation],
                complete: bool,
                clash: tuple[Sequence[Observation], Sequence[Observation]] | None = None
                ) -> str:
        """One paragraph a technician can act on; ``clash`` is :meth:`contradiction`'s
        answer when no diagnosis exists."""
        total = self._held
        if not failed:
            return f"All {total} current observations are OK; no component is suspected."
        listed = "; ".join(f"{o.observer} on {o.resource.label()} ({o.code.name})"
                           for o in failed[:6])
        more = f" and {len(failed) - 6} more" if len(failed) > 6 else ""
        text = f"{len(failed)} of {total} observations failed: {listed}{more}. "
        if not candidates:
            if complete and clash is not None and clash[0]:
                text += (f"No set of modelled components explains them: "
                         f"{self._observations_words('failed', clash[0])} "
                         + (f"contradict{'s' if len(clash[0]) == 1 else ''} "
                            f"{self._observations_words('passing', clash[1])}, which "
                            f"clear{'s' if len(clash[1]) == 1 else ''} every component "
                            f"that could explain {'it' if len(clash[0]) == 1 else 'them'}"
                            if clash[1] else
                            "cannot all fail together under the model's rules")
                         + "; check the model, the observer configuration or those "
                           "observers.")
            elif complete:
                text += ("No set of modelled components explains them"
                         + (f" with at most {self.max_cardinality} faults" if
                            self.max_cardinality else "")
                         + "; check the model or the observer configuration.")
            else:
                text += "The search ran out of its time budget before finding an explanation."
            return text
        best = candidates[0]
        verb = "is" if len(best) == 1 else "are"
        healthy = self._fact.count(True)
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

    @staticmethod
    def _observations_words(state: str, observations: Sequence[Observation],
                            shown: int = 4) -> str:
        """``the failed relation on /a -> /b and hz on /c``."""
        words = [f"{o.observer} on {o.resource.label()}" for o in observations[:shown]]
        if len(observations) > shown:
            words.append(f"{len(observations) - shown} more")
        joined = words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
        return f"the {state} {joined}"

    def _listing(self, sets: Sequence[frozenset[str]], shown: int = 3) -> str:
        words = "; ".join(self._set_words(c) for c in sets[:shown])
        return words + (f" (and {len(sets) - shown} more)" if len(sets) > shown else "")
