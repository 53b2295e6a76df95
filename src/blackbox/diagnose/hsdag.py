"""Minimal hitting sets by Greiner's corrected HS-DAG (Greiner, Smith, Wilkerson 1989).

Reiter's HS-tree computes diagnoses as minimal hitting sets of conflicts, calling the theorem
prover lazily at each node. With conflicts that are not minimal its pruning rule can cut away
the only path to a minimal hitting set. Greiner et al. fix this by building a DAG instead of a
tree: a node is identified by its path set, so two paths to the same set share one node, and
pruning only removes a node once no parent points at it any more.

The search is breadth first, so hitting sets come out by increasing cardinality and the
result found so far is always correct and minimal: that is what makes the time budget
*anytime*. Two bounds stop it early: ``max_cardinality`` (no path longer than that) and
``minimum_only`` (stop after the first level that produced a hitting set, which gives all
minimum-cardinality diagnoses).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T", bound=Hashable)

Prover = Callable[[frozenset[T]], frozenset[T] | None]
"""Given a path set H, returns a conflict disjoint from H, or ``None`` if H is a diagnosis."""


@dataclass(slots=True, eq=False)
class _Node(Generic[T]):
    path: frozenset[T]
    label: frozenset[T] | None = None
    done: bool = False
    hit: bool = False
    pruned: bool = False
    children: dict[T, _Node[T]] = field(default_factory=dict)
    parents: list[_Node[T]] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class HittingSets(Generic[T]):
    """Result of one HS-DAG run.

    ``complete`` is false when the time budget ran out before the bounded search finished.
    ``conflicts`` are the conflicts known at the end (reusable by the next run).
    """

    sets: tuple[frozenset[T], ...]
    complete: bool
    conflicts: tuple[frozenset[T], ...]
    prover_calls: int
    nodes: int


def _sort_key(s: frozenset) -> tuple[int, list[str]]:
    return (len(s), sorted(map(str, s)))


def hs_dag(prover: Prover[T], *, conflicts: Iterable[frozenset[T]] = (),
           max_cardinality: int | None = None, minimum_only: bool = False,
           deadline: float | None = None, clock: Callable[[], float] = time.perf_counter,
           ) -> HittingSets[T]:
    """All minimal hitting sets (diagnoses) up to the bounds, best effort until ``deadline``.

    ``conflicts`` are known conflicts to reuse before asking the prover (Reiter's reuse rule).
    ``deadline`` is a value of ``clock``.
    """
    known: list[frozenset[T]] = sorted(set(conflicts), key=_sort_key)
    found: list[frozenset[T]] = []
    root: _Node[T] = _Node(frozenset())
    by_path: dict[frozenset[T], _Node[T]] = {root.path: root}
    queue: deque[_Node[T]] = deque([root])
    labelled: list[_Node[T]] = []
    calls = 0
    complete = True
    bound = max_cardinality
    smallest = 1 << 30
    order: dict[frozenset[T], list[T]] = {}

    def detach(parent: _Node[T], element: T) -> None:
        child = parent.children.pop(element)
        child.parents.remove(parent)
        if not child.parents:
            child.pruned = True
            if by_path.get(child.path) is child:
                del by_path[child.path]
            for e in list(child.children):
                detach(child, e)

    def prune_with(new: frozenset[T]) -> None:
        """Greiner's pruning: a smaller conflict relabels nodes whose label contains it."""
        for m in labelled:
            if m.pruned or m.label is None or not new < m.label:
                continue
            for e in m.label - new:
                if e in m.children:
                    detach(m, e)
            m.label = new
        known[:] = [c for c in known if not new < c]

    while queue:
        n = queue.popleft()
        if n.pruned or n.done:
            continue
        if bound is not None and len(n.path) > bound:
            continue
        if deadline is not None and clock() >= deadline:
            complete = False
            break
        n.done = True
        if smallest < len(n.path) and any(d <= n.path for d in found):
            continue
        label = next((c for c in known if not (c & n.path)), None)
        if label is None:
            calls += 1
            label = prover(n.path)
            if label is None:
                n.hit = True
                found.append(n.path)
                smallest = min(smallest, len(n.path))
                if minimum_only and (bound is None or bound > len(n.path)):
                    bound = len(n.path)
                continue
            label = frozenset(label)
            if label & n.path:
                raise ValueError(f"prover returned conflict {set(label)} not disjoint from "
                                 f"path {set(n.path)}")
            if not label:
                return HittingSets((), True, (label,), calls, len(by_path))
            prune_with(label)
            known.append(label)
            known.sort(key=_sort_key)
        n.label = label
        labelled.append(n)
        if bound is not None and len(n.path) >= bound:
            continue
        elements = order.get(label)
        if elements is None:
            elements = order[label] = sorted(label, key=str)
        for e in elements:
            path = n.path | {e}
            child = by_path.get(path)
            if child is None:
                child = _Node(path)
                by_path[path] = child
                queue.append(child)
            n.children[e] = child
            child.parents.append(n)

    sets = tuple(sorted(found, key=_sort_key))
    return HittingSets(sets, complete, tuple(known), calls, len(by_path))


def minimal_hitting_sets(conflicts: Iterable[Iterable[T]], **bounds: object
                         ) -> HittingSets[T]:
    """Minimal hitting sets of an explicit collection of sets (the prover picks, in the given
    order, the first set the path does not hit)."""
    family = [frozenset(c) for c in conflicts]

    def prover(path: frozenset[T]) -> frozenset[T] | None:
        return next((c for c in family if not (c & path)), None)

    return hs_dag(prover, **bounds)  # type: ignore[arg-type]
