"""Incremental re-diagnosis is an optimisation only: after any sequence of updates the engine
says exactly what an engine built from scratch says about the same observations (same
candidates in the same order, same failed list, same words), and its candidates are the
minimal diagnoses a plain HS-DAG over solver conflicts finds, without reused conflicts, the
result cache, the conflicts read off failed clauses of components alone or the assumption
literals left out as pure."""

from __future__ import annotations

import random

import pytest

from blackbox.diagnose.engine import DiagnosisEngine, Key
from blackbox.diagnose.hsdag import hs_dag
from blackbox.diagnose.robot_model import NodeSpec, ObservationSpec, Propagation, RobotModel
from blackbox.model import Code, Observation, Resource

MAX_CARDINALITY = 3


def generated_model(n: int, rng: random.Random) -> RobotModel:
    """Layered pipelines with a second publisher on one topic, hardware behind two drivers,
    rate, time-out, value and resource observers."""
    nodes, obs = [], []
    for i in range(n):
        subs = () if i < 3 else tuple(sorted({f"/t{rng.randrange(max(0, i - 6), i)}"
                                              for _ in range(rng.randint(1, 2))}))
        pubs = (f"/t{i}", "/t4") if i == 5 else (f"/t{i}",)
        hardware = (f"/hw{i}",) if i in (0, 1) else ()
        nodes.append(NodeSpec(f"/n{i}", pubs, subs, hardware))
        obs.append(ObservationSpec("activated", Resource(node=f"/n{i}")))
        obs.append(ObservationSpec("hz", Resource(topic=f"/t{i}")))
        obs.append(ObservationSpec("timeout", Resource(topic=f"/t{i}")))
        if i % 3 == 0:
            obs.append(ObservationSpec("scores", Resource(topic=f"/t{i}")))
        if i % 4 == 1:
            obs.append(ObservationSpec("resources", Resource(node=f"/n{i}")))
    return RobotModel(tuple(nodes), tuple(obs))


def world_codes(model: RobotModel, dead: set[str], stalled: set[str], wrong: set[str]
                ) -> dict[Key, Code]:
    """Dead nodes fail ``activated`` and silence everything downstream; a stalled topic is
    silent on its own (its subscribers keep publishing: evidence to learn from); a wrong
    topic fails its ``scores``."""
    silent: set[str] = set()
    for node in sorted(model.nodes, key=lambda s: int(s.name[2:])):
        if node.name in dead or any(t in silent for t in node.sub):
            silent.update(node.pub)
    silent |= stalled
    codes: dict[Key, Code] = {}
    for spec in model.observations:
        r = spec.resource
        bad = ((spec.type in ("activated", "resources") and r.node in dead)
               or (spec.type in ("hz", "timeout") and r.topic in silent)
               or (spec.type == "scores" and r.topic in wrong))
        codes[spec.key()] = Code.NO_STATE_FITS if bad else Code.GENERAL_OK
    return codes


def plain_candidates(engine: DiagnosisEngine) -> set[frozenset[str]]:
    """Minimal diagnoses from a plain HS-DAG asking the solver for every conflict, with
    every assumption literal (also those the engine leaves out as pure)."""
    facts = sorted(lit for lit in engine._assign.tolist() if lit)

    def prover(path: frozenset[str]) -> frozenset[str] | None:
        c = engine.checker.conflict(facts, path)
        return None if c is None else c.components

    res = hs_dag(prover, max_cardinality=MAX_CARDINALITY)
    assert res.complete
    return set(res.sets)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_incremental_updates_say_what_a_fresh_engine_says(seed: int) -> None:
    rng = random.Random(seed)
    model = generated_model(24, rng)
    propagation = Propagation(learn_after=2.0)
    engine = DiagnosisEngine(model, max_cardinality=MAX_CARDINALITY, time_budget=30.0,
                             propagation=propagation)
    names = [n.name for n in model.nodes]
    topics = [f"/t{i}" for i in range(len(names))]
    held: dict[Key, Observation] = {}
    dead: set[str] = set()
    stalled: set[str] = set()
    wrong: set[str] = set()
    extra = Observation(0.0, "resources", Resource(node="/extra"), Code.GENERAL_OK)
    now = 0.0
    for step in range(60):
        now += rng.choice((0.5, 1.0, 1.5))
        if rng.random() < 0.3:  # the world changes now and then, and stays a while
            dead = set(rng.sample(names, rng.choice((0, 0, 1, 1, 2))))
            stalled = set(rng.sample(topics, rng.choice((0, 1, 1, 2))))
            wrong = set(rng.sample(topics, rng.choice((0, 0, 1))))
        codes = world_codes(model, dead, stalled, wrong)
        batch = []
        for key, code in codes.items():
            if rng.random() < 0.25:
                continue  # not every observer reports every time
            if rng.random() < 0.05:
                code = Code.NOT_AVAILABLE
            if rng.random() < 0.03:  # the same key twice in one call: the later one counts
                batch.append(Observation(now, key[0], key[1], Code.GENERAL_ERROR))
            batch.append(Observation(now, key[0], key[1], code))
        if step == 20:  # an observation the model did not declare extends it
            extra = Observation(now, "resources", Resource(node="/extra"), Code.GENERAL_ERROR)
            batch.append(extra)
        elif step > 20 and rng.random() < 0.2:
            extra = Observation(now, "resources", Resource(node="/extra"),
                                rng.choice((Code.GENERAL_OK, Code.GENERAL_ERROR)))
            batch.append(extra)
        rng.shuffle(batch)
        blamed = engine.blamed
        engine.update(now, batch)
        for obs in batch:
            held[obs.key()] = obs
        mine = engine.current()

        fresh = DiagnosisEngine(engine.model, max_cardinality=MAX_CARDINALITY,
                                time_budget=30.0, propagation=propagation,
                                independent=engine.independent, cache_size=0,
                                blamed=blamed)
        fresh.update(now, list(held.values()))
        theirs = fresh.current()
        assert [o.key() for o in mine.failed] == [o.key() for o in theirs.failed], step
        order = [(o.observer, o.resource.label()) for o in mine.failed]
        assert order == sorted(order), step  # failed list: by observer, then resource
        assert mine.candidates == theirs.candidates, step
        assert mine.complete and theirs.complete
        # A failed observation whose code changed but still fails changes no fact, so the
        # engine keeps the diagnosis it has; its words about the same failures are the same.
        assert engine.explain(mine.candidates, theirs.failed, True) == theirs.explanation, step
        if mine.failed:  # with nothing failed the engine suspects nobody (no search)
            assert set(mine.candidates) == plain_candidates(fresh), step
        # The edges with evidence for learning, kept up to date from the changed
        # observations, are those a full look at every watched edge finds.
        assert set(engine._evidencing) == {w[0] for w in engine._watch if engine._evidences(w)}
    assert engine.independent, "the sequence never learnt an edge: it tests too little"


def test_a_dead_node_is_isolated_without_asking_the_solver_for_a_conflict() -> None:
    """A failed ``activated`` clause names the node alone: it is a conflict as it stands, so
    the only solver call left is the check that the hitting set is consistent."""
    model = generated_model(24, random.Random(5))
    engine = DiagnosisEngine(model)
    engine.update(0.0, [Observation(0.0, s.type, s.resource, Code.GENERAL_OK)
                        for s in model.observations])
    calls = engine.checker.calls
    codes = world_codes(model, {"/n7"}, set(), set())
    d = engine.update(1.0, [Observation(1.0, k[0], k[1], c) for k, c in codes.items()])
    assert d is not None and [set(c) for c in d.candidates] == [{"/n7"}]
    assert engine.checker.calls == calls + 1
