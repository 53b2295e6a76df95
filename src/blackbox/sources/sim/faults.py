"""Faults to inject into a simulated robot, random campaigns, and the ground truth log.

A :class:`Fault` says what goes wrong, where and when; the simulator makes it happen and
logs a :class:`GroundTruth` record for every fault it actually injected, which is what
detection and diagnosis results are scored against.
"""

from __future__ import annotations

import json
import math
import random
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from blackbox.config.node import ConfigNode

from . import fault_draws
from .messages import ScalarModel, ValueModel, scalars_of
from .motion import Motion
from .topology import Topology


@dataclass(frozen=True, slots=True)
class FaultKind:
    """What a kind of fault acts on and which parameters it takes.

    ``target`` is ``node``, ``topic`` or ``value`` (a topic with a numeric value model).
    ``params`` lists alternatives: exactly one of them must be given (none if empty).
    """

    name: str
    target: str
    params: tuple[str, ...] = ()
    positive: bool = False
    doc: str = ""


FAULT_KINDS: Mapping[str, FaultKind] = MappingProxyType({k.name: k for k in (
    FaultKind("kill", "node", doc="the process dies; restarts with a new pid at the end"),
    FaultKind("stall", "topic", doc="the topic stops publishing, its node stays alive"),
    FaultKind("rate", "topic", ("factor", "hz"), positive=True,
              doc="publishing rate multiplied by factor or set to hz"),
    FaultKind("offset", "value", ("value",), doc="value + value"),
    FaultKind("scale", "value", ("factor",), doc="value * factor"),
    FaultKind("stuck", "value", doc="value frozen at the last value before the fault"),
    FaultKind("drift", "value", ("rate",), doc="value + rate * (t - start)"),
    FaultKind("noise", "value", ("sigma",), positive=True,
              doc="value + gaussian noise of std sigma (a noisy sensor inside its range)"),
    FaultKind("cpu_hog", "node", ("percent",), positive=True, doc="node CPU raised to percent"),
    FaultKind("memory_growth", "node", ("rate",), positive=True,
              doc="node memory grows by rate bytes per second"),
)})

# The thesis injected killed nodes, an unplugged camera (a stalled topic), changed camera
# and signal rates and a changed signal magnitude (section 6.2.1.2).
THESIS_FAULT_KINDS: tuple[str, ...] = ("kill", "stall", "rate", "offset", "scale")


@dataclass(frozen=True, slots=True)
class Fault:
    """One fault: ``kind`` on ``component`` (node or topic name) from ``start`` to ``end``.

    ``end`` ``None`` means the fault lasts to the end of the run. ``field`` names the one
    numeric field a value fault acts on when the topic has several (``velocity[2]``);
    ``None`` means every numeric field of the topic.
    """

    kind: str
    component: str
    start: float
    end: float | None = None
    params: Mapping[str, float] = field(default_factory=dict)
    field: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))
        problem = self._problem()
        if problem:
            raise ValueError(f"{self.kind} fault on {self.component}: {problem}")

    def _problem(self) -> str | None:
        spec = FAULT_KINDS.get(self.kind)
        if spec is None:
            return f"unknown fault kind; expected one of {', '.join(FAULT_KINDS)}"
        if not (math.isfinite(self.start) and self.start >= 0):
            return f"start must be a time >= 0, got {self.start!r}"
        if self.end is not None and not (math.isfinite(self.end) and self.end > self.start):
            return f"end must be after start ({self.start:g}), got {self.end!r}"
        given = set(self.params)
        unknown = given - set(spec.params)
        if unknown:
            allowed = ", ".join(spec.params) or "none"
            return f"unknown parameter {sorted(unknown)[0]!r} (allowed: {allowed})"
        if self.field is not None and spec.target != "value":
            return f"only value faults name a field, not {self.kind}"
        if spec.params and len(given) != 1:
            return f"give exactly one of {', '.join(spec.params)}"
        for key, value in self.params.items():
            if isinstance(value, bool) or not isinstance(value, int | float):
                return f"{key} must be a number, got {value!r}"
            if not math.isfinite(value) or (spec.positive and value <= 0):
                return f"{key} must be a {'positive' if spec.positive else 'finite'} number"
        return None

    @property
    def target(self) -> str:
        return FAULT_KINDS[self.kind].target

    def node(self, topology: Topology) -> str:
        """The node this fault lives in (the publisher, for topic faults)."""
        if self.target == "node":
            return self.component
        return topology.topics[self.component].publisher

    def check(self, topology: Topology) -> None:
        """Raise ``ValueError`` if this fault cannot happen on ``topology``."""
        where = f"{self.kind} fault on {self.component}"
        if self.target == "node":
            if self.component not in topology.nodes:
                raise ValueError(f"{where}: no node {self.component} in robot {topology.name}")
            return
        topic = topology.topics.get(self.component)
        if topic is None:
            raise ValueError(f"{where}: no topic {self.component} in robot {topology.name}")
        fields = [s.field for s in scalars_of(topic.value)]
        if self.target == "value" and not fields:
            raise ValueError(f"{where}: the topic has no numeric value model")
        if self.field is not None and self.field not in fields:
            raise ValueError(f"{where}: no modelled field {self.field!r} "
                             f"(fields: {', '.join(fields)})")

    def acts_on(self, field_name: str) -> bool:
        """Whether this value fault changes ``field_name`` of its topic."""
        return self.field is None or self.field == field_name


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """A fault the simulator injected. ``end`` is ``None`` while it is still active."""

    start: float
    end: float | None
    kind: str
    component: str
    node: str
    params: Mapping[str, float] = field(default_factory=dict)
    field: str | None = None
    """The one field a value fault acted on, ``None`` for all of its topic's."""

    def to_dict(self) -> dict[str, Any]:
        out = {"start": self.start, "end": self.end, "kind": self.kind,
               "component": self.component, "node": self.node, "params": dict(self.params)}
        if self.field is not None:
            out["field"] = self.field
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GroundTruth:
        return cls(float(d["start"]), None if d.get("end") is None else float(d["end"]),
                   str(d["kind"]), str(d["component"]), str(d.get("node", d["component"])),
                   dict(d.get("params", {})),
                   None if d.get("field") is None else str(d["field"]))


def write_ground_truth(records: Iterable[GroundTruth], path: str | Path) -> None:
    """Write records as JSON lines, one fault per line."""
    with Path(path).open("w", encoding="utf-8") as f:
        for r in records:
            f.write(json.dumps(r.to_dict(), sort_keys=True) + "\n")


def read_ground_truth(path: str | Path) -> list[GroundTruth]:
    with Path(path).open(encoding="utf-8") as f:
        return [GroundTruth.from_dict(json.loads(line)) for line in f if line.strip()]


# ---- random campaigns ------------------------------------------------------------------------

def _components(topology: Topology, kind: str, moving_only: bool = False) -> list[str]:
    target = FAULT_KINDS[kind].target
    if target == "node":
        return list(topology.nodes)
    if target == "topic":
        return list(topology.topics)
    return [t.name for t in topology.topics.values() if _faultable(t.value, moving_only)]


def _faultable(model: ValueModel | None, moving_only: bool) -> list[ScalarModel]:
    return [s for s in scalars_of(model) if s.follows or not moving_only]


def noise_std(model: ScalarModel) -> float:
    """Standard deviation of a value model's own measurement noise."""
    if model.distribution == "gauss":
        return model.noise
    return model.noise / math.sqrt(3.0)


def healthy_spread(model: ScalarModel, topology: Topology, horizon: float = 600.0,
                   step: float = 0.5) -> float:
    """Standard deviation of a healthy value over ``horizon`` seconds (seed 0): its noise
    and the motion it follows, sampled, so modes, trends and derived signals count."""
    if not model.follows:
        return noise_std(model)
    cached = _SPREADS.get((id(topology), model))
    if cached is not None and cached[0] is topology:
        return cached[1]
    motion = Motion(topology.motion, topology.modes, seed=0)
    total = [sum(gain * motion.at(signal, k * step) for signal, gain in model.follows)
             for k in range(int(horizon / step))]
    spread = fault_draws.spread(total, noise_std(model))
    _SPREADS[(id(topology), model)] = (topology, spread)
    return spread


# Campaigns ask for the same spreads again and again; the topology is kept with its entry so
# its id cannot be reused by another one.
_SPREADS: dict[tuple[int, ScalarModel], tuple[Topology, float]] = {}


def _random_params(rng: random.Random, kind: str, topology: Topology,
                   model: ScalarModel | None) -> dict[str, float]:
    """Parameters large enough to be a real fault, drawn around the component's nominal
    (``model``: the numeric field a value fault acts on; :mod:`.fault_draws` draws them)."""
    if kind == "rate":
        return fault_draws.rate(rng)
    if kind in ("offset", "drift"):
        assert model is not None
        if model.follows:
            # A moving signal's mean says nothing about its scale: its noise does, or for a
            # noiseless counter a hundredth of its healthy spread.
            unit = max(model.noise, 1e-3)
            if model.noise == 0.0:
                unit = max(unit, 0.01 * healthy_spread(model, topology))
        else:
            unit = max(model.noise, 0.05 * abs(model.mean), 1e-3)
        return fault_draws.offset(rng, unit) if kind == "offset" else \
            fault_draws.drift(rng, unit)
    if kind == "scale":
        return fault_draws.scale(rng)
    if kind == "noise":
        assert model is not None
        return fault_draws.noise(rng, healthy_spread(model, topology), noise_std(model))
    if kind == "cpu_hog":
        return fault_draws.cpu_hog(rng)
    if kind == "memory_growth":
        return fault_draws.memory_growth(rng)
    return {}


def random_campaign(
    topology: Topology,
    duration: float,
    seed: int,
    kinds: Sequence[str] | Mapping[str, Mapping[str, float]] = tuple(FAULT_KINDS),
    mean_gap: float = 10.0,
    duration_range: tuple[float, float] = (5.0, 15.0),
    warmup: float = 5.0,
    min_separation: float = 0.0,
    moving_only: bool = False,
) -> list[Fault]:
    """Random faults over ``[warmup, duration)``, reproducible for a ``seed``.

    Fault starts form a Poisson process with ``mean_gap`` seconds between them; each picks
    a kind (uniformly among ``kinds`` with a free component), then a free component and
    parameters (random, or fixed when ``kinds`` maps a kind to its parameters). Faults never
    overlap on the same node, counting a topic as part of its publisher, and the next fault
    on a node starts at least ``min_separation`` seconds after the previous one ended.
    A start with no free component is skipped. ``moving_only``: value faults only on
    fields that follow the robot's motion (its correlated signals), not on constants.
    """
    if duration <= 0 or mean_gap <= 0 or warmup < 0 or min_separation < 0:
        raise ValueError("duration and mean_gap must be > 0, warmup and min_separation >= 0")
    low, high = duration_range
    if not 0 < low <= high:
        raise ValueError(f"duration_range must satisfy 0 < low <= high, got {duration_range}")
    fixed: Mapping[str, Mapping[str, float]] = (
        kinds if isinstance(kinds, Mapping) else {k: {} for k in kinds})
    for k in fixed:
        if k not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {k!r}; expected one of {', '.join(FAULT_KINDS)}")
    rng = random.Random(f"blackbox-sim-campaign:{seed}")
    free_at = {n: 0.0 for n in topology.nodes}
    owner = {t.name: t.publisher for t in topology.topics.values()}

    def free(kind: str, t: float) -> list[str]:
        return [c for c in _components(topology, kind, moving_only)
                if free_at[owner.get(c, c)] <= t]

    faults: list[Fault] = []
    for draw in fault_draws.draws(rng, duration, fixed, free, warmup=warmup,
                                  mean_gap=mean_gap, lengths=(low, high)):
        kind, component = draw.kind, draw.component
        model: ScalarModel | None = None
        field_name: str | None = None
        if FAULT_KINDS[kind].target == "value":
            # A topic with several fields: one of them lies (drawn only then, so campaigns
            # on single-field robots stay as they were).
            every = scalars_of(topology.topics[component].value)
            scalars = _faultable(topology.topics[component].value, moving_only)
            model = scalars[0] if len(scalars) == 1 else rng.choice(scalars)
            field_name = None if len(every) == 1 else model.field
        params = dict(fixed[kind]) or _random_params(rng, kind, topology, model)
        start = round(draw.t, 3)
        end = round(draw.t + draw.length, 3)
        faults.append(Fault(kind, component, start, end, params, field_name))
        free_at[owner.get(component, component)] = end + min_separation
    return faults


# ---- YAML ------------------------------------------------------------------------------------

def load_faults(source: str | Path | ConfigNode, topology: Topology) -> list[Fault]:
    """Faults from YAML: a ``faults:`` list and/or a ``random:`` campaign (docs/simulator.md)."""
    root = source if isinstance(source, ConfigNode) else ConfigNode.load(source)
    root.check_keys(["faults", "random"])
    faults: list[Fault] = []
    items = root.get("faults")
    for item in items.list() if items is not None else []:
        faults.append(_fault(item, topology))
    campaign = root.get("random")
    if campaign is not None:
        faults.extend(_campaign(campaign, topology))
    return sorted(faults, key=lambda f: f.start)


def _fault(item: ConfigNode, topology: Topology) -> Fault:
    item.check_keys(["kind", "component", "start", "end", "field",
                     *{p for k in FAULT_KINDS.values() for p in k.params}])
    kind = item["kind"].str(FAULT_KINDS)
    spec = FAULT_KINDS[kind]
    for key, child in item.items():
        if key not in ("kind", "component", "start", "end", "field") and key not in spec.params:
            allowed = ", ".join(spec.params) or "none"
            raise child.error(f"{kind} takes no parameter {key!r} (allowed: {allowed})")
    params = {p: item[p].float(min_exclusive=spec.positive, min=0.0 if spec.positive else None)
              for p in spec.params if item.get(p) is not None}
    if spec.params and len(params) != 1:
        raise item.error(f"a {kind} fault needs exactly one of {', '.join(spec.params)}")
    start = item["start"].float(min=0.0)
    end = item["end"].float(min=start, min_exclusive=True) if item.get("end") else None
    field_node = item.get("field")
    try:
        fault = Fault(kind, item["component"].str(), start, end, params,
                      field_node.str() if field_node is not None else None)
    except ValueError as exc:
        raise (field_node or item).error(str(exc)) from None
    try:
        fault.check(topology)
    except ValueError as exc:
        raise item["component"].error(str(exc)) from None
    return fault


def _campaign(node: ConfigNode, topology: Topology) -> list[Fault]:
    node.check_keys(["duration", "seed", "kinds", "mean_gap", "duration_range", "warmup",
                     "min_separation"])
    kinds: Sequence[str] | Mapping[str, Mapping[str, float]] = tuple(FAULT_KINDS)
    kinds_node = node.get("kinds")
    if kinds_node is not None and kinds_node.is_map:
        mapping: dict[str, dict[str, float]] = {}
        for kind, params in kinds_node.items():
            if kind not in FAULT_KINDS:
                raise params.error(f"unknown fault kind {kind!r}")
            mapping[kind] = ({} if params.is_null else
                             {k: v.float() for k, v in params.items()})
        kinds = mapping
    elif kinds_node is not None:
        kinds = tuple(k.str(FAULT_KINDS) for k in kinds_node.list(allow_single=True))
    duration_range = (5.0, 15.0)
    dr = node.get("duration_range")
    if dr is not None:
        pair = dr.list()
        if len(pair) != 2:
            raise dr.error("expected [shortest, longest] in seconds")
        duration_range = (pair[0].float(min=0.0, min_exclusive=True),
                          pair[1].float(min=0.0, min_exclusive=True))

    def opt(key: str, default: float) -> float:
        child = node.get(key)
        return child.float(min=0.0) if child is not None else default

    try:
        return random_campaign(
            topology, node["duration"].float(min=0.0, min_exclusive=True),
            node["seed"].int() if node.get("seed") is not None else 0, kinds,
            mean_gap=opt("mean_gap", 10.0), duration_range=duration_range,
            warmup=opt("warmup", 5.0), min_separation=opt("min_separation", 0.0))
    except ValueError as exc:
        raise node.error(str(exc)) from None


__all__ = ["FAULT_KINDS", "THESIS_FAULT_KINDS", "Fault", "FaultKind", "GroundTruth", "load_faults",
           "random_campaign", "read_ground_truth", "write_ground_truth"]
