"""Audit a DXC scenario's published ambiguity group against the shipped netlist.

A benchmark score is only as good as its ground truth. The published group is meant to be
the set of minimum-cardinality diagnoses of the scenario's observation; this module checks
that claim with two independent means: the consistency-based engine enumerates the
minimum-cardinality diagnoses, and every disagreement is backed by a *witness* that plain
simulation of the netlist confirms (the witness gates giving the opposite of their function
reproduce every sensor reading exactly). A witness is therefore a checkable fact about the
shipped files, not an artefact of the SAT encoding.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from blackbox.diagnose.dxc import Circuit, CircuitDiagnoser, Gate, Scenario

_FUNCTIONS: dict[str, Callable[[list[bool]], object]] = {
    "and": all,
    "or": any,
    "nand": lambda v: not all(v),
    "nor": lambda v: not any(v),
    "xor": lambda v: sum(v) % 2 == 1,
    "xnor": lambda v: sum(v) % 2 == 0,
    "not": lambda v: not v[0],
    "buffer": lambda v: v[0],
}

VERDICTS = ("agrees", "incomplete", "overstated minimum", "contradicts", "not minimum",
            "undecided")
"""``agrees``: the group is exactly the minimum-cardinality diagnoses; ``incomplete``: same
minimum, but diagnoses of that size are missing from it; ``overstated minimum``: a smaller
diagnosis exists; ``contradicts``: a member of the group does not explain the observation;
``not minimum``: the group holds every minimum-cardinality diagnosis and larger ones too;
``undecided``: the engine did not finish in its time limit or the scenario has no group."""


def topological_order(circuit: Circuit) -> tuple[Gate, ...]:
    """Gates ordered so that every gate comes after the gates driving its inputs."""
    driver = {g.output: g for g in circuit.gates}
    done: set[str] = set()
    order: list[Gate] = []
    for root in circuit.gates:
        stack: list[tuple[Gate, bool]] = [(root, False)]
        while stack:
            gate, expanded = stack.pop()
            if gate.name in done:
                continue
            if expanded:
                done.add(gate.name)
                order.append(gate)
                continue
            stack.append((gate, True))
            stack.extend((driver[n], False) for n in gate.inputs
                         if n in driver and driver[n].name not in done)
    return tuple(order)


def simulate(order: tuple[Gate, ...], inputs: Mapping[str, bool],
             inverted: frozenset[str] = frozenset()) -> dict[str, bool]:
    """Every net's value; gates named in ``inverted`` output the opposite of their function."""
    values = dict(inputs)
    for g in order:
        values[g.output] = bool(_FUNCTIONS[g.function]([values[n] for n in g.inputs])) != (
            g.name in inverted)
    return values


def explains(order: tuple[Gate, ...], observations: Mapping[str, bool],
             abnormal: frozenset[str]) -> bool:
    """Whether ``abnormal`` is a diagnosis under the weak fault model: each abnormal gate may
    give either output, so some subset of them inverted must reproduce the observation."""
    gates = sorted(abnormal)
    return any(reproduces(order, observations,
                          frozenset(g for i, g in enumerate(gates) if mask >> i & 1))
               for mask in range(1 << len(gates)))


def reproduces(order: tuple[Gate, ...], observations: Mapping[str, bool],
               inverted: frozenset[str]) -> bool:
    """Whether inverting exactly these gates yields every observed sensor value."""
    driven = {g.output for g in order}
    inputs = {k: v for k, v in observations.items() if k not in driven}
    values = simulate(order, inputs, inverted)
    return all(values[k] == v for k, v in observations.items())


@dataclass(frozen=True, slots=True)
class GroundTruthAudit:
    """What the published group of one scenario is, measured against the netlist.

    ``witness`` is a diagnosis confirmed by simulation that the group should contain but
    does not (for ``incomplete`` and ``overstated minimum``) or a member of the group that
    fails to explain the observation (for ``contradicts``). ``not_minimal`` counts members
    of the group that strictly contain a smaller diagnosis.
    """

    scenario: str
    verdict: str
    published: int
    published_minimum: int
    found: int
    minimum: int
    injected: frozenset[str]
    injected_reproduces: bool
    injected_in_group: bool
    not_minimal: int
    witness: frozenset[str] | None


def audit(diagnoser: CircuitDiagnoser, scenario: Scenario, limit: float = 10.0
          ) -> GroundTruthAudit:
    """Compare ``scenario``'s published group with the minimum-cardinality diagnoses."""
    order = topological_order(diagnoser.circuit)
    injected = frozenset().union(*scenario.injected)
    injected_ok = reproduces(order, scenario.observations, injected)
    group = set(scenario.ambiguity_group or ())
    sets, complete, _ = diagnoser.diagnose(scenario.observations, limit)
    found = set(sets)
    minimum = min((len(s) for s in found), default=0)
    published_minimum = min((len(s) for s in group), default=0)
    not_minimal = sum(1 for t in group if any(s < t for s in found))

    def verdict() -> tuple[str, frozenset[str] | None]:
        if not group or not complete:
            return "undecided", None
        facts = diagnoser.facts(scenario.observations)
        wrong = next((t for t in sorted(group, key=sorted)
                      if diagnoser.checker.conflict(facts, t) is not None
                      and not explains(order, scenario.observations, t)), None)
        if wrong is not None:
            return "contradicts", wrong
        missing = sorted(found - group, key=lambda s: (s != injected, sorted(s)))
        if missing:
            witness = next((s for s in missing
                            if reproduces(order, scenario.observations, s)), None)
            if witness is None:  # the engine and the simulator disagree: claim nothing
                return "undecided", None
            return ("overstated minimum" if len(witness) < published_minimum
                    else "incomplete"), witness
        larger = sorted(group - found, key=sorted)
        return ("not minimum", larger[0]) if larger else ("agrees", None)

    name, witness = verdict()
    return GroundTruthAudit(scenario.name, name, len(group), published_minimum, len(found),
                            minimum, injected, injected_ok, injected in group, not_minimal, witness)
