"""DX Competition (DXC'09 synthetic track) circuits: system catalogs, scenarios and the score.

A system catalog lists components (gates, ``wire`` pins named ``gate.pin``, ``probe``
junctions and ``port`` sensors) and connections from a pin to the net it touches. Only gates
can fail; their fault mode produces "an arbitrary output", which is the *weak fault model*:
a healthy gate computes its function, an abnormal one is unconstrained.

A scenario (``.scn``) holds sensor readings before and after a fault injection, the true
ambiguity group (``ambiguityGroup ... diagnoses = { {g1, g2}, ... }``, the scenario's last
diagnostic line) and the ``normalizationFactor`` that makes reporting exactly that group
score 1. The first sensor line, taken before the injection with the same inputs, carries
nothing the netlist does not already say (the fault-free outputs), so the last one is
diagnosed.

What is *reported* for a scenario is a decision under the benchmark's utility: by default
the one minimum-cardinality diagnosis with the highest mean utility against all of them
(the Bayes choice when each is taken as equally likely to be the truth), or all of them.
"""

from __future__ import annotations

import re
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blackbox.config.node import ConfigError
from blackbox.diagnose.hsdag import hs_dag
from blackbox.diagnose.sat import ConsistencyChecker, Theory

_NS = "{urn:org:dx-competition:system}"

BASELINES: dict[str, dict[str, float]] = {
    "74L85": {"no-fault": 0.657, "random single gate": 0.661, "single-fault simulation": 0.749},
}
"""Published baseline scores quoted in the project issue (only 74L85 is given there)."""
REPORTS = ("best", "all")
"""``best``: the minimum-cardinality diagnosis of highest expected utility; ``all``: every
minimum-cardinality diagnosis found."""
GATE_FUNCTIONS = ("and", "or", "nand", "nor", "xor", "xnor", "not", "buffer")
_TYPE_RE = re.compile(r"^(and|or|nand|nor|xor|xnor|inverter|not|buffer)(\d*)$")


@dataclass(frozen=True, slots=True)
class Gate:
    name: str
    function: str
    inputs: tuple[str, ...]
    output: str


@dataclass(frozen=True, slots=True)
class Circuit:
    """A combinational circuit: gates over named nets; ``ports`` are the observable nets."""

    name: str
    gates: tuple[Gate, ...]
    ports: tuple[str, ...]

    @property
    def gate_names(self) -> tuple[str, ...]:
        return tuple(g.name for g in self.gates)


@dataclass(frozen=True, slots=True)
class Scenario:
    name: str
    observations: dict[str, bool]
    injected: tuple[frozenset[str], ...]
    ambiguity_group: tuple[frozenset[str], ...] | None
    normalization: float | None

    @property
    def scored(self) -> bool:
        """Whether the benchmark has a ground truth (its generator may have timed out)."""
        return self.ambiguity_group is not None and self.normalization is not None


def _function_of(type_name: str) -> str | None:
    m = _TYPE_RE.match(type_name)
    if not m:
        return None
    fn = m.group(1)
    return "not" if fn == "inverter" else fn


def load_catalog(path: str | Path) -> Circuit:
    """Read a DXC system catalog (XML); errors name the file."""
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ConfigError(f"cannot read DXC system catalog: {exc}", str(p)) from None
    system = root.find(f"{_NS}systems/{_NS}system")
    if system is None:
        raise ConfigError("no <system> in DXC system catalog", str(p))
    name = system.findtext(f"{_NS}systemName") or p.stem
    types: dict[str, str] = {}
    for comp in system.iterfind(f"{_NS}components/{_NS}component"):
        cname = comp.findtext(f"{_NS}name")
        ctype = comp.findtext(f"{_NS}componentType")
        if cname and ctype:
            types[cname] = ctype
    net_of: dict[str, str] = {}
    for conn in system.iterfind(f"{_NS}connections/{_NS}connection"):
        a, b = conn.findtext(f"{_NS}c1"), conn.findtext(f"{_NS}c2")
        if not a or not b:
            raise ConfigError("connection without c1/c2", str(p))
        pin, net = (a, b) if "." in a else (b, a)
        net_of[pin] = net
    gates: list[Gate] = []
    for cname, ctype in types.items():
        if ctype in ("wire", "probe", "port"):
            continue
        fn = _function_of(ctype)
        if fn is None:
            raise ConfigError(f"component {cname!r} has unsupported type {ctype!r}; supported "
                              f"gate types: {', '.join(GATE_FUNCTIONS)}", str(p))
        pins = sorted((pin for pin in net_of if pin.startswith(cname + ".")),
                      key=lambda s: (len(s), s))
        inputs = tuple(net_of[pin] for pin in pins if pin != f"{cname}.o")
        out = net_of.get(f"{cname}.o")
        if out is None or not inputs:
            raise ConfigError(f"gate {cname!r} is not fully connected", str(p))
        gates.append(Gate(cname, fn, inputs, out))
    ports = tuple(c for c, t in types.items() if t == "port")
    return Circuit(name, tuple(gates), ports)


_SENSORS = re.compile(r"^sensors\s+@\d+\s*\{(.*)\}\s*;", re.M)
_INJECT = re.compile(r"^faultInjection\b.*?fault\s*=\s*\{(.*?)\}", re.M)
_AMBIG = re.compile(r"^ambiguityGroup\b.*?diagnoses\s*=\s*\{(.*)\}\s*;", re.M)
_NORM = re.compile(r"^normalizationFactor\s*=\s*([0-9.eE+-]+)\s*;", re.M)


def _sets(text: str) -> tuple[frozenset[str], ...]:
    return tuple(frozenset(x.strip() for x in body.split(",") if x.strip())
                 for body in re.findall(r"\{([^{}]*)\}", text))


def load_scenario(path: str | Path) -> Scenario:
    """Read a ``.scn`` file: the last sensor line is the observation to diagnose."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read scenario: {exc}", str(p)) from None
    sensors = _SENSORS.findall(text)
    ambig = _AMBIG.findall(text)
    norm = _NORM.findall(text)
    if not sensors or not ambig:
        raise ConfigError("scenario needs sensors and ambiguityGroup lines", str(p))
    obs: dict[str, bool] = {}
    for item in sensors[-1].split(","):
        key, _, value = item.partition("=")
        v = value.strip().lower()
        if v not in ("true", "false"):
            raise ConfigError(f"sensor {key.strip()!r} has non-boolean value {value!r}", str(p))
        obs[key.strip()] = v == "true"
    injected = tuple(frozenset(k.split("=")[0].strip() for k in body.split(",") if k.strip())
                     for body in _INJECT.findall(text))
    truth = None if "TIMEOUT" in ambig[-1] else (_sets(ambig[-1]) or (frozenset(),))
    factor = float(norm[-1]) if norm else None
    return Scenario(p.stem, obs, injected, truth, factor)


def encode(circuit: Circuit, theory: Theory) -> None:
    """Weak fault model clauses: not AB(g) -> out(g) = function(inputs(g))."""
    for g in circuit.gates:
        ab = theory.ab(g.name)
        ins = [theory.var(("net", n)) for n in g.inputs]
        out = theory.var(("net", g.output))
        fn = g.function
        negate = fn in ("nand", "nor", "xnor", "not")
        base = {"nand": "and", "nor": "or", "xnor": "xor", "not": "buffer"}.get(fn, fn)
        if base == "xor" and len(ins) > 2:
            acc = ins[0]
            for x in ins[1:-1]:
                aux = theory.fresh()
                _xor_clauses(theory, None, aux, acc, x)
                acc = aux
            ins = [acc, ins[-1]]
        o = -out if negate else out
        if base == "and":
            for x in ins:
                theory.add([ab, -o, x])
            theory.add([ab, o, *(-x for x in ins)])
        elif base == "or":
            for x in ins:
                theory.add([ab, o, -x])
            theory.add([ab, -o, *ins])
        elif base == "xor":
            if len(ins) == 1:
                ins = [ins[0], ins[0]]
            _xor_clauses(theory, ab, o, ins[0], ins[1])
        else:  # buffer
            theory.add([ab, -o, ins[0]])
            theory.add([ab, o, -ins[0]])


def _xor_clauses(theory: Theory, ab: int | None, o: int, a: int, b: int) -> None:
    guard = [ab] if ab is not None else []
    theory.add([*guard, -o, a, b])
    theory.add([*guard, -o, -a, -b])
    theory.add([*guard, o, -a, b])
    theory.add([*guard, o, a, -b])


def utility(w: frozenset[str], truth: frozenset[str], f: int) -> float:
    """The DXC pairwise utility m(w, w*) with n false positives, nbar false negatives,
    N = |w|, Nbar = f - N over f gates."""
    n = len(w - truth)
    nbar = len(truth - w)
    big_n = len(w)
    big_nbar = f - big_n
    return 1.0 - n * (big_n + 1) / (f * (n + 1)) - nbar * (big_nbar + 1) / (f * (nbar + 1))


def utility_matrix(diagnoses: Sequence[frozenset[str]], truth: Sequence[frozenset[str]],
                   f: int) -> np.ndarray:
    """``m(w, t)`` for every ``w`` in ``diagnoses`` (rows) and ``t`` in ``truth`` (columns).

    The utility only depends on the sizes and the overlap, and overlaps of all pairs are one
    matrix product of 0/1 incidence matrices.
    """
    names = {g: i for i, g in enumerate(sorted(set().union(*diagnoses, *truth)))}

    def incidence(sets: Sequence[frozenset[str]]) -> np.ndarray:
        out = np.zeros((len(sets), max(len(names), 1)), dtype=np.float64)
        for row, s in enumerate(sets):
            out[row, [names[g] for g in s]] = 1.0
        return out

    w, t = incidence(diagnoses), incidence(truth)
    overlap = w @ t.T
    size_w = w.sum(axis=1)[:, None]
    size_t = t.sum(axis=1)[None, :]
    n = size_w - overlap
    nbar = size_t - overlap
    utility: np.ndarray = (1.0 - n * (size_w + 1) / (f * (n + 1))
                           - nbar * (f - size_w + 1) / (f * (nbar + 1)))
    return utility


def score(diagnoses: Sequence[frozenset[str]], truth: Sequence[frozenset[str]], f: int,
          normalization: float) -> float:
    """Mean utility over all pairs, divided by the scenario's normalization factor.

    Reporting no fault counts as the single empty diagnosis.
    """
    ds = list(diagnoses) or [frozenset()]
    ts = list(truth) or [frozenset()]
    return float(utility_matrix(ds, ts, f).mean()) / normalization


def best_diagnosis(diagnoses: Sequence[frozenset[str]], f: int,
                   block: int = 1024) -> frozenset[str]:
    """The diagnosis with the highest mean utility against all of ``diagnoses``.

    The score averages over every reported diagnosis, so reporting several can only do as
    well as the best of them; with each of the candidates equally likely to be the truth,
    this one maximises the expected utility. Ties go to the first in name order.
    """
    ds = sorted(diagnoses, key=lambda s: (len(s), sorted(s)))
    if len(ds) <= 1:
        return ds[0] if ds else frozenset()
    means = np.concatenate([utility_matrix(ds[i:i + block], ds, f).mean(axis=1)
                            for i in range(0, len(ds), block)])
    return ds[int(np.argmax(means))]


@dataclass(frozen=True, slots=True)
class ScenarioResult:
    """``diagnoses`` is what was reported (``D``); ``minimum`` counts the minimum-cardinality
    diagnoses it was chosen from."""

    scenario: str
    diagnoses: tuple[frozenset[str], ...]
    complete: bool
    seconds: float
    score: float | None
    prover_calls: int
    minimum: int = 0


class CircuitDiagnoser:
    """One circuit encoded once; every scenario only changes the assumption literals."""

    def __init__(self, circuit: Circuit) -> None:
        self.circuit = circuit
        self.theory = Theory()
        encode(circuit, self.theory)
        for port in circuit.ports:
            self.theory.var(("net", port))
        self.checker = ConsistencyChecker(self.theory, circuit.gate_names)

    def facts(self, observations: dict[str, bool]) -> list[int]:
        out = []
        for net, value in observations.items():
            v = self.theory.var(("net", net))
            out.append(v if value else -v)
        return out

    def diagnose(self, observations: dict[str, bool], limit: float = 1.0,
                 max_cardinality: int | None = None) -> tuple[tuple[frozenset[str], ...], bool,
                                                             int]:
        """Minimum-cardinality diagnoses found within ``limit`` seconds."""
        start = time.perf_counter()
        deadline = start + 0.9 * limit
        facts = self.facts(observations)

        def prover(path: frozenset[str]) -> frozenset[str] | None:
            c = self.checker.conflict(facts, path, deadline, time.perf_counter)
            return None if c is None else c.components

        res = hs_dag(prover, minimum_only=True, max_cardinality=max_cardinality,
                     deadline=deadline, clock=time.perf_counter)
        return res.sets, res.complete, res.prover_calls

    def run(self, scenario: Scenario, limit: float = 1.0, report: str = "best"
            ) -> ScenarioResult:
        """Diagnose one scenario and score what ``report`` (one of :data:`REPORTS`) picks;
        the choice counts against the time limit."""
        if report not in REPORTS:
            raise ValueError(f"report must be one of {REPORTS}, got {report!r}")
        t0 = time.perf_counter()
        sets, complete, calls = self.diagnose(scenario.observations, limit)
        f = len(self.circuit.gates)
        reported = (best_diagnosis(sets, f),) if report == "best" and sets else sets
        dt = time.perf_counter() - t0
        s = None
        if scenario.ambiguity_group is not None and scenario.normalization is not None:
            s = score(reported, scenario.ambiguity_group, f, scenario.normalization)
        return ScenarioResult(scenario.name, reported, complete, dt, s, calls, len(sets))


def scenario_files(directory: str | Path) -> list[Path]:
    return sorted(Path(directory).glob("*.scn"))


def run_model(model: str | Path, scenarios: Iterable[str | Path], limit: float = 1.0,
              report: str = "best") -> list[ScenarioResult]:
    diagnoser = CircuitDiagnoser(load_catalog(model))
    return [diagnoser.run(load_scenario(s), limit, report) for s in scenarios]
