"""No module outside an observer's own decides by its type name.

What the other stages need to know about an observer type (its subject, whether its
failure means silence, how many numbers it logs, ...) is declared where the type registers
(:class:`~blackbox.observe.base.ObserverKind`). A module that compares an observation's type
with ``"timeout"`` or keeps a table keyed by type names goes stale the day a type is added
(a one-file plug-in in ``tests/plugins`` would be treated as unknown there). The source is
read with ``ast``: a comparison of a type-like name (``s.type``, ``o.characteristic``,
``kind``) with an observer type's name, or a dictionary literal keyed by two or more of
them, is reported with its file and line.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import blackbox
from blackbox.observe.base import OBSERVERS

PACKAGE_ROOT = Path(blackbox.__file__).parent
OWN_MODULES = PACKAGE_ROOT / "observe" / "observers"
"""Each observer type's own module (and its shared helpers) may name it."""
TYPE_LIKE = frozenset({"type", "type_name", "characteristic", "observer", "observer_type",
                       "kind"})


def observer_names() -> frozenset[str]:
    return frozenset(n for name, kind in OBSERVERS.items() for n in (name, *kind.aliases))


def _strings(node: ast.expr) -> list[str]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return [s for e in node.elts for s in _strings(e)]
    return []


def _type_like(node: ast.expr) -> bool:
    name = node.attr if isinstance(node, ast.Attribute) else \
        node.id if isinstance(node, ast.Name) else ""
    return name in TYPE_LIKE


def name_matches(source: str, names: frozenset[str]) -> Iterator[tuple[int, str]]:
    """(line, what) for each place ``source`` decides by an observer type's name."""
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            named = sorted({s for o in operands for s in _strings(o) if s in names})
            if named and any(_type_like(o) for o in operands):
                yield node.lineno, f"compares a type with {named}"
        elif isinstance(node, ast.Dict):
            keys = sorted({s for k in node.keys if k is not None for s in _strings(k)
                           if s in names})
            if len(keys) >= 2:
                yield node.lineno, f"a table keyed by observer types {keys}"


def test_no_module_outside_the_registry_matches_observer_type_names() -> None:
    names = observer_names()
    assert {"hz", "timeout", "activated"} <= names
    found = [f"{path.relative_to(PACKAGE_ROOT.parent)}:{line}: {what}"
             for path in sorted(PACKAGE_ROOT.rglob("*.py")) if OWN_MODULES not in path.parents
             for line, what in name_matches(path.read_text(), names)]
    assert not found, ("observer type names matched outside the registry; declare the fact "
                       "on ObserverKind instead:\n" + "\n".join(found))


def test_the_scan_finds_a_comparison_and_a_table_by_type_name() -> None:
    """The scanner itself: the forms it must catch, and names it must leave alone."""
    names = frozenset({"timeout", "activated"})
    source = ("a = [s for s in specs if s.type == 'timeout']\n"
              "b = o.characteristic in ('activated', 'x')\n"
              "c = {'activated': 0, 'timeout': 1}.get(kind, 2)\n"
              "d = {'type': 'timeout', 'topic': '/a'}\n"  # building an entry is fine
              "e = 'timeout' in node\n")  # a configuration key, not a type
    assert sorted(line for line, _ in name_matches(source, names)) == [1, 2, 3]
