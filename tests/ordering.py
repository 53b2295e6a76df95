"""Longest tests first, so parallel workers finish together.

pytest-xdist hands tests to workers in collection order. A 100 s test collected near the
end starts when the other workers are almost done and the run waits for it alone; handed
out first, it runs while the other workers take the many short tests. ``tests/slowest.txt``
lists the tests measured slow (seconds and node id, longest first; a node id without its
``[parameters]`` covers every case); :func:`longest_first` moves them to the front.
Tests that share a worker through ``xdist_group`` are one unit of work: the unit's seconds
are the sum of its tests' and the unit moves as a whole, its tests in their own order.
``scripts/test.sh`` runs xdist with ``--no-loadscope-reorder``: by default xdist sorts the
units by their number of tests, which put a 160 s group of two tests behind a 20 s group
of forty. A stale or missing line costs only speed, never a test.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

SLOWEST = Path(__file__).with_name("slowest.txt")


class Marker(Protocol):
    args: tuple[object, ...]
    kwargs: dict[str, object]


class Item(Protocol):
    nodeid: str

    def get_closest_marker(self, name: str) -> Marker | None: ...


def expected_seconds(path: Path = SLOWEST) -> dict[str, float]:
    """Node id (or node id without parameters) -> measured seconds, from ``path``."""
    seconds: dict[str, float] = {}
    if not path.exists():
        return seconds
    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        value, _, nodeid = line.partition(" ")
        try:
            seconds[nodeid.strip()] = float(value)
        except ValueError:
            continue  # a malformed line costs only its test's place in the queue
    return seconds


def _seconds(nodeid: str, table: dict[str, float]) -> float:
    nodeid = nodeid.split("@", 1)[0]  # xdist may have added its group ("...@group")
    if nodeid in table:
        return table[nodeid]
    return table.get(nodeid.split("[", 1)[0], 0.0)


def unit(item: Item) -> str:
    """The unit of work xdist's ``loadgroup`` hands out whole: the group, else the test."""
    marker = item.get_closest_marker("xdist_group")
    if marker is None:
        return item.nodeid
    name = marker.args[0] if marker.args else marker.kwargs.get("name", "default")
    return f"@{name}"


def longest_first(items: Sequence[Item], table: dict[str, float]) -> list[Item]:
    """``items`` by unit of work, the units with listed seconds first, longest first; the
    rest keep their order, and so do the tests inside a unit."""
    units: dict[str, list[Item]] = {}
    for item in items:
        units.setdefault(unit(item), []).append(item)
    seconds = {name: sum(_seconds(item.nodeid, table) for item in members)
               for name, members in units.items()}
    order = sorted(units, key=lambda name: -seconds[name])  # stable: unlisted keep order
    return [item for name in order for item in units[name]]
