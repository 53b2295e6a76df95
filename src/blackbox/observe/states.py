"""States of an observed resource: numbered, named sets of checks, one per quantity.

An observer measures one or more quantities (``period`` for hz, ``cpu`` and ``memory`` for
resources, ...), filters each into a :class:`~blackbox.observe.base.Summary` and asks which
configured states fit. A state fits when every check it gives passes; a quantity a state
gives no check for is unconstrained in that state, and a quantity without a summary yet
(no samples) makes every state that checks it unfit. All fitting states are reported; none
fitting is ``NO_STATE_FITS``. An observer configured without states is always
``GENERAL_OK``: it only reports its values.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

from blackbox.config.node import ConfigNode
from blackbox.model import Code, State
from blackbox.observe.base import Check, Summary
from blackbox.observe.checks import build_check


@dataclass(frozen=True, slots=True, eq=False)
class StateSpec:
    """One configured state: its number, name and the check of each quantity it constrains."""

    number: int
    name: str
    checks: Mapping[str, Check]

    @property
    def state(self) -> State:
        return State(self.number, self.name)

    def fits(self, summaries: Mapping[str, Summary | None]) -> bool:
        for quantity, check in self.checks.items():
            summary = summaries.get(quantity)
            if summary is None or not check.test(summary):
                return False
        return True

    def describe(self) -> str:
        checks = "; ".join(f"{q}: {c.describe()}" for q, c in self.checks.items())
        return f"state {self.number} {self.name!r}" + (f": {checks}" if checks else "")


def _state_name(node: ConfigNode) -> str:
    v = node.raw
    if isinstance(v, int) and not isinstance(v, bool):
        return str(v)
    if not isinstance(v, str) or not v:
        hint = "; quote it, for example name: 'off'" if isinstance(v, bool) else ""
        raise node.error(f"a state name must be a non-empty string, got {v!r}{hint}")
    return v


def parse_states(node: ConfigNode | None, quantities: Sequence[str]) -> tuple[StateSpec, ...]:
    """The ``states`` list of an observer whose quantities are ``quantities``.

    Each entry has ``number`` (int), ``name`` (``state`` is accepted as its tug spelling)
    and one check per quantity it constrains (an empty check accepts everything).
    """
    if node is None or node.is_null:
        return ()
    quantities = tuple(quantities)
    allowed = ("number", "name", "state", *quantities)
    where = f" ({', '.join(quantities)})" if quantities else ""
    specs: list[StateSpec] = []
    numbers: dict[int, ConfigNode] = {}
    for entry in node.list():
        if not entry.is_map:
            raise entry.error("a state is a mapping with 'number', 'name' and one check per "
                              f"quantity{where}")
        entry.check_keys(allowed)
        number_node = entry["number"]
        number = number_node.int()
        if number in numbers:
            raise number_node.error(f"duplicate state number {number} (first used at line "
                                    f"{numbers[number].line})")
        numbers[number] = number_node
        named = entry.first("name", "state")
        if named is None:
            raise entry.error("missing required key 'name'")
        name = _state_name(named[1])
        checks = {q: build_check(entry.get(q)) for q in quantities if q in entry}
        if quantities and not checks:
            raise entry.error(f"state {number} ({name!r}) checks nothing; give a check for "
                              f"{' or '.join(repr(q) for q in quantities)}")
        specs.append(StateSpec(number, name, MappingProxyType(checks)))
    return tuple(specs)


def fitting_states(states: Sequence[StateSpec],
                   summaries: Mapping[str, Summary | None]) -> tuple[State, ...]:
    """Every state whose checks all pass, in configuration order."""
    return tuple(spec.state for spec in states if spec.fits(summaries))


def states_code(states: Sequence[StateSpec], fitting: Sequence[State]) -> Code:
    """``GENERAL_OK`` when a state fits or none is configured, else ``NO_STATE_FITS``."""
    return Code.GENERAL_OK if fitting or not states else Code.NO_STATE_FITS


def evaluate_states(states: Sequence[StateSpec], summaries: Mapping[str, Summary | None]
                    ) -> tuple[Code, tuple[State, ...]]:
    """The observation code and the fitting states for one set of summaries."""
    fitting = fitting_states(states, summaries)
    return states_code(states, fitting), fitting


def describe_states(states: Sequence[StateSpec], separator: str = "\n") -> str:
    """One line per state for ``check-config``, or the states joined by ``separator``."""
    if not states:
        return "no states: always GENERAL_OK"
    return separator.join(spec.describe() for spec in states)
