"""Parallel workers get the longest units of work first (tests/ordering.py), so no 100 s test
starts when the others are done: a group's tests go as one unit weighing their sum, in
their own order; unlisted tests keep their order."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ordering import SLOWEST, expected_seconds, longest_first


@dataclass
class Mark:
    args: tuple[object, ...]
    kwargs: dict[str, object] = field(default_factory=dict)


@dataclass
class FakeItem:
    nodeid: str
    group: str | None = None

    def get_closest_marker(self, name: str) -> Mark | None:
        return Mark((self.group,)) if name == "xdist_group" and self.group else None


def test_listed_tests_go_first_longest_first_and_the_rest_keep_their_order() -> None:
    items = [FakeItem("a.py::quick"), FakeItem("b.py::slow"), FakeItem("c.py::slower[x]"),
             FakeItem("e.py::other")]
    table = {"b.py::slow": 20.0, "c.py::slower": 90.0}
    ordered = [item.nodeid for item in longest_first(items, table)]
    assert ordered == ["c.py::slower[x]", "b.py::slow", "a.py::quick", "e.py::other"]


def test_a_group_moves_as_one_unit_weighing_the_sum_of_its_tests() -> None:
    items = [FakeItem("a.py::quick"), FakeItem("b.py::slow"),
             FakeItem("g1.py::first", group="g"), FakeItem("x.py::grouped_short", group="h"),
             FakeItem("g2.py::second", group="g"), FakeItem("c.py::slower")]
    table = {"b.py::slow": 20.0, "c.py::slower": 90.0, "g1.py::first": 50.0,
             "g2.py::second": 60.0}
    ordered = [item.nodeid for item in longest_first(items, table)]
    assert ordered == ["g1.py::first", "g2.py::second", "c.py::slower", "b.py::slow",
                       "a.py::quick", "x.py::grouped_short"]


def test_the_table_reads_seconds_and_node_ids_and_skips_what_it_cannot_read(
        tmp_path: Path) -> None:
    path = tmp_path / "slowest.txt"
    path.write_text("# comment\n12.5 t.py::one\n\nnot-a-number t.py::two\n3 t.py::three  # why\n")
    assert expected_seconds(path) == {"t.py::one": 12.5, "t.py::three": 3.0}
    assert expected_seconds(tmp_path / "missing.txt") == {}


def test_every_listed_test_file_exists() -> None:
    root = SLOWEST.parent.parent
    missing = sorted({nodeid.split("::")[0] for nodeid in expected_seconds()
                      if not (root / nodeid.split("::")[0]).is_file()})
    assert not missing, f"tests/slowest.txt names files that are gone: {missing}"
