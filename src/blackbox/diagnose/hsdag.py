"""Minimal hitting sets by Greiner's corrected HS-DAG (Greiner, Smith, Wilkerson 1989).

Reiter's HS-tree computes diagnoses as minimal hitting sets of conflicts, calling the theorem
prover lazily at each node. With conflicts that are not minimal its pruning rule can cut away
the only path to a minimal hitting set. Greiner et al. fix this by building a DAG instead of a
tree: a node is identified by its path set, so two paths to the same set share one node, and
pruning only removes a node once no parent points at it any more.

The search runs level by level (breadth first), so hitting sets come out by increasing
cardinality and the result found so far is always correct and minimal: that is what makes the
time budget *anytime*. Two bounds stop it early: ``max_cardinality`` (no path longer than
that) and ``minimum_only`` (stop after the first level that produced a hitting set, which
gives all minimum-cardinality diagnoses).

Sets are Python ints used as bitsets (one bit per element), so a path, a label and every
subset test is a handful of machine-word operations. Three observations keep the work down:

* A node is labelled with the smallest known conflict it does not hit, found with one mask
  per element ("conflicts containing e"): the conflicts disjoint from a path are the live ones
  outside the union of its elements' masks, a union a child gets from its parent with one
  more OR. Only when none is left is the prover asked.
* Reiter's closing rule (a path containing a known hitting set is closed) can only apply to a
  path that hits every known conflict, and only when some element of it has no *private*
  known conflict (one that meets the path in that element alone); otherwise the path is
  minimal for the known conflicts and cannot contain a smaller hitting set. A hitting set
  inside the path must hold the private elements and the element the path was reached by,
  which leaves few candidates to look up.
* A strictly smaller new conflict relabels the nodes whose label contains it; the edges for
  the dropped elements disappear with the old label, and nodes no longer reachable from the
  root are pruned before their level is expanded (Greiner's pruning, batched per level).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable, Iterable, Iterator
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T", bound=Hashable)

Prover = Callable[[frozenset[T]], frozenset[T] | None]
"""Given a path set H, returns a conflict disjoint from H, or ``None`` if H is a diagnosis."""


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


def _sort_key(s: frozenset[object]) -> tuple[int, list[str]]:
    return (len(s), sorted(map(str, s)))


def _bits(x: int) -> Iterator[int]:
    """The single-bit ints of ``x``, lowest first."""
    while x:
        low = x & -x
        yield low
        x ^= low


class _Elements(Generic[T]):
    """Element <-> bit, allocated on first sight."""

    def __init__(self) -> None:
        self.bit: dict[T, int] = {}
        self.items: list[T] = []

    def encode(self, elements: Iterable[T]) -> int:
        out = 0
        for e in elements:
            b = self.bit.get(e)
            if b is None:
                b = self.bit[e] = 1 << len(self.items)
                self.items.append(e)
            out |= b
        return out

    def decode(self, x: int) -> frozenset[T]:
        items = self.items
        return frozenset(items[b.bit_length() - 1] for b in _bits(x))


class _Conflicts:
    """An antichain of conflicts (bitsets) with per-element and per-size index masks.

    Conflict ``i`` is bit ``1 << i`` of the index masks; a conflict made redundant by a
    smaller one is dropped from ``live``.
    """

    def __init__(self) -> None:
        self.sets: list[int] = []
        self.live = 0
        self.containing: dict[int, int] = {}
        self.by_size: dict[int, int] = {}
        self._sizes: list[int] = []

    def add(self, c: int) -> list[int]:
        """Add ``c``; returns the known conflicts it made redundant (strict supersets).
        A conflict that contains a known one is not added."""
        removed = []
        for idx in _bits(self.live):
            old = self.sets[idx.bit_length() - 1]
            if old & c == old:
                return []
            if old & c == c:
                removed.append(old)
                self.live &= ~idx
        i = 1 << len(self.sets)
        self.sets.append(c)
        self.live |= i
        for b in _bits(c):
            self.containing[b] = self.containing.get(b, 0) | i
        size = c.bit_count()
        if size not in self.by_size:
            self.by_size[size] = 0
            self._sizes = sorted(self.by_size)
        self.by_size[size] |= i
        return removed

    def masks(self, path: int) -> tuple[int, int]:
        """Conflicts (index masks) meeting ``path`` at least once and at least twice."""
        containing = self.containing
        once = twice = 0
        x = path
        while x:
            b = x & -x
            m = containing.get(b, 0)
            twice |= once & m
            once |= m
            x ^= b
        return once, twice

    def label(self, path: int, once: int, twice: int) -> tuple[int, int]:
        """``(conflict, 0)`` with the smallest live conflict disjoint from ``path``, or, when
        ``path`` hits them all, ``(0, private)``: the elements of ``path`` that have a live
        conflict meeting ``path`` there alone. When that is all of ``path``, no proper subset
        of it hits every known conflict. ``once``, ``twice`` are :meth:`masks` of ``path``."""
        containing = self.containing
        free = self.live & ~once
        if free:
            for size in self._sizes:
                m = free & self.by_size[size]
                if m:
                    return self.sets[(m & -m).bit_length() - 1], 0
        alone = once & ~twice & self.live
        private = 0
        x = path
        while x:
            b = x & -x
            if containing.get(b, 0) & alone:
                private |= b
            x ^= b
        return 0, private

    def live_sets(self) -> list[int]:
        return [self.sets[i.bit_length() - 1] for i in _bits(self.live)]


def hs_dag(prover: Prover[T], *, conflicts: Iterable[frozenset[T]] = (),
           max_cardinality: int | None = None, minimum_only: bool = False,
           deadline: float | None = None, clock: Callable[[], float] = time.perf_counter,
           ) -> HittingSets[T]:
    """All minimal hitting sets (diagnoses) up to the bounds, best effort until ``deadline``.

    ``conflicts`` are known conflicts to reuse before asking the prover (Reiter's reuse rule).
    ``deadline`` is a value of ``clock``.
    """
    elements: _Elements[T] = _Elements()
    known = _Conflicts()
    for c in sorted(dict.fromkeys(map(frozenset, conflicts)), key=len):
        if not c:
            return HittingSets((), True, (c,), 0, 1)
        known.add(elements.encode(c))
    found: list[int] = []
    found_set: set[int] = set()
    found_with: dict[int, int] = {}  # element bit -> mask over indices into ``found``
    labels: dict[int, int] = {}
    # path -> (an element bit by which it was reached, masks of the path, number of known
    # conflicts the masks cover)
    level: dict[int, tuple[int, int, int, int]] = {0: (0, 0, 0, 0)}
    calls = 0
    nodes = 1
    complete = True
    bound = max_cardinality
    k = 0

    def result() -> HittingSets[T]:
        sets = sorted((elements.decode(h) for h in found), key=_sort_key)
        known_sets = sorted((elements.decode(c) for c in known.live_sets()), key=len)
        return HittingSets(tuple(sets), complete, tuple(known_sets), calls, nodes)

    def closed(path: int, needed: int) -> bool:
        """Whether ``path`` contains a hitting set found earlier that contains ``needed``.

        Such a set is ``path`` minus a non-empty part of the other elements: with few of
        those, look the candidates up; otherwise scan the found sets holding ``needed``."""
        optional = path & ~needed
        if 0 < optional.bit_count() <= 4:
            bits = list(_bits(optional))
            for r in range(1, 1 << len(bits)):
                drop = 0
                for j, b in enumerate(bits):
                    if r >> j & 1:
                        drop |= b
                if path & ~drop in found_set:
                    return True
            return False
        if not needed:
            return any(h & path == h for h in found)
        candidates = -1
        x = needed
        while x:
            b = x & -x
            candidates &= found_with.get(b, 0)
            x ^= b
        while candidates:
            i = candidates & -candidates
            h = found[i.bit_length() - 1]
            if h & path == h:
                return True
            candidates ^= i
        return False

    while level:
        expand: list[int] = []
        relabelled = False
        masks: dict[int, tuple[int, int, int]] = {}
        for path, (via, once, twice, covered) in level.items():
            if deadline is not None and clock() >= deadline:
                complete = False
                return result()
            if covered != len(known.sets):
                once, twice = known.masks(path)
                covered = len(known.sets)
            label, private = known.label(path, once, twice)
            if not label:
                # A found hitting set inside ``path`` holds ``via`` (else it would lie inside
                # the parent, which hits no hitting set) and every element with a private
                # known conflict (else it would miss that conflict).
                if private != path and closed(path, private | via):
                    continue
                calls += 1
                answer = prover(elements.decode(path))
                if answer is None:
                    i = 1 << len(found)
                    found.append(path)
                    found_set.add(path)
                    for b in _bits(path):
                        found_with[b] = found_with.get(b, 0) | i
                    continue
                if not answer:
                    return HittingSets((), True, (frozenset(),), calls, nodes)
                label = elements.encode(answer)
                if label & path:
                    raise ValueError(f"prover returned conflict {set(answer)} not disjoint "
                                     f"from path {set(elements.decode(path))}")
                removed = known.add(label)
                if removed:
                    relabelled |= _relabel(labels, removed, label)
            labels[path] = label
            masks[path] = (once, twice, covered)
            expand.append(path)
        if minimum_only and found:
            break
        if relabelled:
            expand = _reachable_only(labels, expand)
        if bound is not None and k >= bound:
            break
        nxt: dict[int, tuple[int, int, int, int]] = {}
        containing = known.containing
        for path in expand:
            once, twice, covered = masks[path]
            for b in _bits(labels[path]):
                child = path | b
                if child not in nxt:
                    m = containing.get(b, 0)
                    nxt[child] = (b, once | m, twice | once & m, covered)
        nodes += len(nxt)
        level = nxt
        k += 1
    return result()


def _relabel(labels: dict[int, int], removed: list[int], new: int) -> bool:
    """Greiner's relabelling: nodes labelled with a conflict that the smaller ``new`` made
    redundant are labelled ``new`` instead (disjoint from their path, as the old label was)."""
    gone = set(removed)
    changed = False
    for path, label in labels.items():
        if label in gone:
            labels[path] = new
            changed = True
    return changed


def _reachable_only(labels: dict[int, int], expand: list[int]) -> list[int]:
    """Drop the labelled nodes no parent points at any more (Greiner's pruning) and return
    the nodes of ``expand`` that are still reachable from the root."""
    reached = {0}
    frontier = [0]
    while frontier:
        nxt = []
        for path in frontier:
            label = labels.get(path)
            if label is None:
                continue
            for b in _bits(label):
                child = path | b
                if child not in reached and child in labels:
                    reached.add(child)
                    nxt.append(child)
        frontier = nxt
    for path in [p for p in labels if p not in reached]:
        del labels[path]
    return [p for p in expand if p in reached]


def minimal_hitting_sets(conflicts: Iterable[Iterable[T]], *, lazy: bool = False,
                         **bounds: object) -> HittingSets[T]:
    """Minimal hitting sets of an explicit collection of sets.

    By default every set is handed to the HS-DAG as a known conflict. With ``lazy=True`` the
    DAG only learns them from a prover that picks, in the given order, the first set the path
    does not hit (possibly a non-minimal one: the case Greiner's pruning exists for).
    """
    family = [frozenset(c) for c in conflicts]

    def prover(path: frozenset[T]) -> frozenset[T] | None:
        return next((c for c in family if not (c & path)), None)

    if lazy:
        return hs_dag(prover, **bounds)  # type: ignore[arg-type]
    return hs_dag(prover, conflicts=family, **bounds)  # type: ignore[arg-type]
