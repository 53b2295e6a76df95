"""Static descriptions of observers: what UCMS specifications and thresholds are made of.

Observations say what was measured, not what the limits are; the limits live in the
configuration's states. :func:`describe_observer` reads one native observer entry
(``docs/configuration.md``) and derives per quantity:

* **thresholds**, the envelope of all states: a ``gauss`` check ``mean +- std_deviation``
  gives a MIN and a MAX, ``in_between`` its bounds, ``greater_than`` a MIN, ``less_than`` a
  MAX. With several states the MIN is the lowest of the states' MINs and exists only when
  every state has one (likewise MAX), because a value is acceptable when any state fits.
  ``exact``, ``not``, ``not_in_between`` and ``student_t`` checks give no threshold.
* **expected noise**: the ``std_deviation`` of a ``gauss`` or ``student_t`` check (the
  largest over the states).
* **filter** type and numeric parameters, and the evaluation interval (``every``).

The quantities, their units and the thresholds every observer of a type has come from the
observer type's own registration (:class:`~blackbox.observe.base.ObserverKind`), and the
resource from the observer the entry builds, so a new observer type is described without
any change here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

from blackbox.config.node import ConfigNode
from blackbox.model import Resource
from blackbox.observe.base import NamedQuantities, observer_kind
from blackbox.observe.build import build_observer, kind_of


def unit_of(observer: str, quantity: str) -> str:
    """The unit of ``quantity`` as the observer type ``observer`` registered it."""
    kind = observer_kind(observer)
    return kind.unit(quantity) if kind is not None else ""


@dataclass(frozen=True, slots=True)
class ThresholdSpec:
    quantity: str
    type: Literal["min", "max"]
    value: float

    @property
    def name(self) -> str:
        return f"{self.quantity} {self.type}"

    def exceeded_by(self, x: float) -> bool:
        return x < self.value if self.type == "min" else x > self.value


@dataclass(frozen=True, slots=True)
class ObserverDescription:
    """What the health mapping knows about one observer before it observes anything."""

    observer: str
    resource: Resource
    interval: float | None = None
    quantities: tuple[str, ...] = ()
    thresholds: tuple[ThresholdSpec, ...] = ()
    expected_noise: Mapping[str, float] = field(default_factory=dict)
    filter_type: str = ""
    filter_parameters: Mapping[str, float] = field(default_factory=dict)
    states: tuple[str, ...] = ()

    def unit(self, quantity: str) -> str:
        return unit_of(self.observer, quantity)


def _bounds(check: ConfigNode) -> tuple[float | None, float | None, float | None]:
    """(min, max, noise) of one quantity's check in one state."""
    if not check.is_map:
        return None, None, None
    raw = check.to_python()
    if raw.get("type") == "student_t":
        noise = raw.get("std_deviation")
        return None, None, float(noise) if isinstance(noise, int | float) else None
    value = raw.get("value")
    if not isinstance(value, dict):
        return None, None, None
    kind = value.get("type")
    num = {k: float(v) for k, v in value.items()
           if isinstance(v, int | float) and not isinstance(v, bool)}
    if kind == "gauss" and {"mean", "std_deviation"} <= num.keys():
        m, sd = num["mean"], num["std_deviation"]
        return m - sd, m + sd, sd
    if kind == "in_between" and {"lower_bound", "upper_bound"} <= num.keys():
        return num["lower_bound"], num["upper_bound"], None
    if kind == "greater_than" and "greater_than" in num:
        return num["greater_than"], None, None
    if kind == "less_than" and "less_than" in num:
        return None, num["less_than"], None
    return None, None, None


def describe_observer(node: ConfigNode) -> ObserverDescription:
    """Describe one native observer entry; raises ``ConfigError`` via ``node.error``."""
    kind = kind_of(node)
    observer = build_observer(node)
    resource = observer.resource
    every = node.get("every")
    interval = every.float(min=0.0, min_exclusive=True) if every is not None else 1.0
    quantities = tuple(q.name for q in kind.quantities)
    if not quantities and isinstance(observer, NamedQuantities):
        quantities = observer.quantity_names()
    states_node = node.get("states")
    states = states_node.list() if states_node is not None else []
    names: list[str] = []
    lows: dict[str, list[float | None]] = {q: [] for q in quantities}
    highs: dict[str, list[float | None]] = {q: [] for q in quantities}
    noise: dict[str, float] = {}
    for state in states:
        if not state.is_map:
            raise state.error("expected a state mapping with number, name and checks")
        name = state.get("name")
        names.append(name.str() if name is not None else str(len(names) + 1))
        for q in quantities:
            check = state.get(q)
            lo, hi, sd = _bounds(check) if check is not None else (None, None, None)
            lows[q].append(lo)
            highs[q].append(hi)
            if sd is not None:
                noise[q] = max(noise.get(q, 0.0), sd)
    thresholds: list[ThresholdSpec] = []
    for q in quantities:
        if lows[q] and all(v is not None for v in lows[q]):
            thresholds.append(ThresholdSpec(q, "min", min(v for v in lows[q] if v is not None)))
        if highs[q] and all(v is not None for v in highs[q]):
            thresholds.append(ThresholdSpec(q, "max", max(v for v in highs[q] if v is not None)))
    thresholds.extend(ThresholdSpec(t.quantity, t.type, t.value) for t in kind.thresholds)
    filter_type, params = "", {}
    filter_keys = [k for k, _ in node.items() if k.endswith("_filter")]
    for key in ("filter", *filter_keys):
        f = node.get(key)
        if f is not None and f.is_map:
            raw = f.to_python()
            filter_type = str(raw.get("type", ""))
            params = {k: float(v) for k, v in raw.items() if isinstance(v, int | float)
                      and not isinstance(v, bool) and math.isfinite(float(v))}
            break
    return ObserverDescription(kind.name, resource, interval, quantities, tuple(thresholds), noise,
                               filter_type, params, tuple(names))


def describe_observers(section: ConfigNode | None) -> list[ObserverDescription]:
    """Descriptions of every entry of a native ``observers`` list."""
    if section is None:
        return []
    return [describe_observer(item) for item in section.list()]
