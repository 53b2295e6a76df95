"""Longest tests first, so parallel workers finish together.

pytest-xdist hands tests to workers in collection order. A 100 s test collected near the
end starts when the other workers are almost done and the run waits for it alone; handed
out first, it runs while the other workers take the many short tests. ``tests/slowest.txt``
lists the tests measured slow (seconds and node id, longest first; a node id without its
``[parameters]`` covers every case); :func:`longest_first` moves them to the front.
Tests that share a worker through ``xdist_group`` stay where they are: xdist hands a group
out as one unit and already starts with the largest groups. A stale or missing line costs
only speed, never a test.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

SLOWEST = Path(__file__).with_name("slowest.txt")


class Item(Protocol):
    nodeid: str

    def get_closest_marker(self, name: str) -> object: ...


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
    if nodeid in table:
        return table[nodeid]
    return table.get(nodeid.split("[", 1)[0], 0.0)


def longest_first(items: Sequence[Item], table: dict[str, float]) -> list[Item]:
    """``items`` with the listed slow ones first, longest first; the rest keep their
    order, and so do tests in an ``xdist_group``."""
    slow = [item for item in items if _seconds(item.nodeid, table) > 0
            and item.get_closest_marker("xdist_group") is None]
    chosen = {id(item) for item in slow}
    slow.sort(key=lambda item: -_seconds(item.nodeid, table))  # stable for equal times
    return [*slow, *(item for item in items if id(item) not in chosen)]
