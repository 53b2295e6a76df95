"""Greiner's HS-DAG: minimal hitting sets, bounds, time budget, reuse."""

from __future__ import annotations

import itertools
import random
from collections import deque

from blackbox.diagnose.hsdag import hs_dag, minimal_hitting_sets


def fs(*names: str) -> frozenset[str]:
    return frozenset(names)


def as_strings(sets) -> set[str]:
    return {"".join(sorted(s)) for s in sets}


def brute_force(family: list[frozenset[str]], universe: str) -> set[frozenset[str]]:
    hitting = [frozenset(c) for r in range(len(universe) + 1)
               for c in itertools.combinations(universe, r)
               if all(set(c) & f for f in family)]
    return {h for h in hitting if not any(o < h for o in hitting)}


def reiter_hs_tree(family: list[frozenset[str]]) -> set[frozenset[str]]:
    """Reiter's original HS-tree (1987) with his closing and pruning rules, kept here only to
    show the case it gets wrong: closing a node because another node has the same path, then
    pruning that other node, loses the path altogether."""
    nodes: list[dict] = []
    root = {"path": frozenset(), "label": None, "children": {}, "alive": True, "seen": False}
    queue = deque([root])
    nodes.append(root)

    def kill(n: dict) -> None:
        n["alive"] = False
        for c in n["children"].values():
            kill(c)

    while queue:
        n = queue.popleft()
        if not n["alive"]:
            continue
        closed = any(m is not n and m["alive"] and (
            (m["label"] == "ok" and m["path"] <= n["path"])
            or (m["path"] == n["path"] and m["seen"])) for m in nodes)
        n["seen"] = True
        if closed:
            continue
        label = next((f for f in family if not f & n["path"]), None)
        if label is None:
            n["label"] = "ok"
            continue
        n["label"] = label
        for m in nodes:
            if m["alive"] and isinstance(m["label"], frozenset) and label < m["label"]:
                for a in m["label"] - label:
                    if a in m["children"]:
                        kill(m["children"].pop(a))
                m["label"] = label
        if not n["alive"]:
            continue
        for a in sorted(n["label"]):
            c = {"path": n["path"] | {a}, "label": None, "children": {}, "alive": True,
                 "seen": False}
            n["children"][a] = c
            nodes.append(c)
            queue.append(c)
    return {m["path"] for m in nodes if m["alive"] and m["label"] == "ok"}


def test_reiter_textbook_conflicts_of_the_full_adder():
    # Reiter 1987: conflicts {X1, X2} and {X1, A2, O1} of the full adder.
    res = minimal_hitting_sets([fs("X1", "X2"), fs("X1", "A2", "O1")])
    assert set(res.sets) == {fs("X1"), fs("X2", "A2"), fs("X2", "O1")}
    assert res.sets[0] == fs("X1")
    assert res.complete


def test_greiner_non_minimal_conflicts():
    # Greiner et al.'s kind of input: conflicts that contain other conflicts.
    family = [fs("a", "b"), fs("b", "c"), fs("a", "c"), fs("b", "d"), fs("b")]
    assert set(minimal_hitting_sets(family).sets) == {fs("a", "b"), fs("b", "c")}


def test_case_plain_reiter_hs_tree_gets_wrong():
    family = [fs("a", "b"), fs("b", "d"), fs("a", "d"), fs("c"), fs("b")]
    truth = {fs("a", "b", "c"), fs("b", "c", "d")}
    assert brute_force(family, "abcd") == truth
    assert reiter_hs_tree(family) == {fs("b", "c", "d")}  # {a, b, c} is lost
    assert set(minimal_hitting_sets(family).sets) == truth
    # Learnt lazily, the conflicts arrive in this order: {a, b} labels the root, then {b}
    # relabels it (Greiner's pruning removes the edge a); the answer is still complete.
    lazy = minimal_hitting_sets(family, lazy=True)
    assert set(lazy.sets) == truth
    assert set(lazy.conflicts) == {fs("b"), fs("c"), fs("a", "d")}  # {a, b}, {b, d} redundant


def test_agrees_with_brute_force_on_random_families():
    rng = random.Random(7)
    for _ in range(300):
        family = [frozenset(rng.sample("abcde", rng.randint(1, 4)))
                  for _ in range(rng.randint(1, 7))]
        assert set(minimal_hitting_sets(family).sets) == brute_force(family, "abcde"), family


def test_agrees_with_brute_force_when_conflicts_are_learnt_non_minimal():
    # The lazy prover hands out the first set the path misses, often a superset of another:
    # relabelling and pruning happen, and must lose nothing.
    rng = random.Random(11)
    universe = "abcdefgh"
    for _ in range(300):
        family = [frozenset(rng.sample(universe, rng.randint(1, 5)))
                  for _ in range(rng.randint(1, 10))]
        truth = brute_force(family, universe)
        assert set(minimal_hitting_sets(family, lazy=True).sets) == truth, family
        assert set(minimal_hitting_sets(family).sets) == truth, family
        smallest = min(map(len, truth))
        assert set(minimal_hitting_sets(family, minimum_only=True, lazy=True).sets) == {
            h for h in truth if len(h) == smallest}, family
        assert set(minimal_hitting_sets(family, max_cardinality=2).sets) == {
            h for h in truth if len(h) <= 2}, family


def test_agrees_with_brute_force_on_ten_elements():
    # Wider paths: closing then has to look past many elements without private conflicts.
    rng = random.Random(2)
    universe = "abcdefghij"
    for _ in range(100):
        family = [frozenset(rng.sample(universe, rng.randint(1, 4)))
                  for _ in range(rng.randint(3, 14))]
        truth = brute_force(family, universe)
        assert set(minimal_hitting_sets(family).sets) == truth, family
        assert set(minimal_hitting_sets(family, lazy=True).sets) == truth, family


def test_anytime_result_is_a_prefix_by_cardinality():
    # Whatever the budget, what comes back is minimal, and every smaller hitting set is in it.
    rng = random.Random(5)
    universe = "abcdefgh"
    family = [frozenset(rng.sample(universe, rng.randint(2, 4))) for _ in range(9)]
    truth = brute_force(family, universe)
    for budget in range(1, 200, 7):
        clock = iter(range(10**6)).__next__  # one unit per look
        res = minimal_hitting_sets(family, deadline=budget, clock=clock)
        got = set(res.sets)
        assert got <= truth
        if not res.complete and got:
            largest = max(map(len, got))
            assert {h for h in truth if len(h) < largest} <= got
        if res.complete:
            assert got == truth


def test_cardinality_bound():
    family = [fs("a", "b"), fs("c", "d"), fs("a", "c", "e")]
    assert as_strings(minimal_hitting_sets(family).sets) == {"ac", "ad", "bc", "bde"}
    bounded = minimal_hitting_sets(family, max_cardinality=2)
    assert as_strings(bounded.sets) == {"ac", "ad", "bc"}
    assert bounded.complete


def test_minimum_only_stops_at_the_first_level_with_hitting_sets():
    family = [fs("a", "b"), fs("c", "d"), fs("a", "c", "e")]
    assert as_strings(minimal_hitting_sets(family, minimum_only=True).sets) == {"ac", "ad", "bc"}


def test_time_budget_returns_best_so_far_marked_incomplete():
    ticks = iter(range(1000))  # a clock that advances one unit per look
    family = [fs("a", "b"), fs("c", "d"), fs("a", "c", "e")]
    res = minimal_hitting_sets(family, deadline=9, clock=lambda: next(ticks))
    assert not res.complete
    assert set(res.sets) < {fs("a", "c"), fs("a", "d"), fs("b", "c"),
                            fs("b", "d", "e")}
    assert all(len(s) == 2 for s in res.sets)  # breadth first: the smallest come first


def test_known_conflicts_are_reused_without_the_prover():
    calls: list[frozenset[str]] = []

    def prover(path: frozenset[str]) -> frozenset[str] | None:
        calls.append(path)
        return None if path & {"a", "b"} and path & {"c"} else fs("a", "b") if not path & {
            "a", "b"} else fs("c")

    res = hs_dag(prover, conflicts=[fs("a", "b"), fs("c")])
    assert set(res.sets) == {fs("a", "c"), fs("b", "c")}
    assert all(len(p) == 2 for p in calls)  # only leaves needed the prover


def test_empty_conflict_means_no_diagnosis():
    res = minimal_hitting_sets([fs()])
    assert res.sets == ()
