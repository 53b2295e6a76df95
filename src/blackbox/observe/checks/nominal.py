"""The ``nominal_value`` check: value checks on the filtered value and on its deviation.

A state fits when the optional ``value`` check passes on the filtered value and every
entry of the optional ``deviation`` list passes on the deviation. An undefined deviation
(the sample standard deviation of a single sample) passes no deviation check: a state that
constrains the spread cannot be confirmed before there is a spread. Without any value or
deviation check (template files leave both empty) the check accepts everything.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

from blackbox.config.node import ConfigNode
from blackbox.observe.base import CHECKS, VALUE_CHECKS, Check, Summary
from blackbox.observe.checks.value import ValueCheck

NOMINAL_VALUE = "nominal_value"


@dataclass(frozen=True, slots=True)
class AcceptAllCheck:
    """An empty check: every summary fits. ``reason`` says why it is empty."""

    reason: str = "no check configured"

    def test(self, summary: Summary) -> bool:
        return True

    def describe(self) -> str:
        return f"accepts every value ({self.reason})"


@dataclass(frozen=True, slots=True)
class NominalValueCheck:
    value: ValueCheck | None = None
    deviation: tuple[ValueCheck, ...] = ()

    def test(self, summary: Summary) -> bool:
        if self.value is not None and not self.value.passes(summary.value):
            return False
        if self.deviation:
            d = summary.deviation
            if d is None:
                return False
            for check in self.deviation:
                if not check.passes(d):
                    return False
        return True

    def describe(self) -> str:
        parts = [self.value.describe("value")] if self.value is not None else []
        parts += [c.describe("deviation") for c in self.deviation]
        return " and ".join(parts) if parts else AcceptAllCheck().describe()


def build_value_check(node: ConfigNode) -> ValueCheck:
    """One value check from a mapping with ``type`` and that type's parameters."""
    if not node.is_map:
        raise node.error("a value check is a mapping with a 'type', "
                         "for example {type: gauss, mean: 15.0, std_deviation: 0.5}")
    kind = node["type"].str(list(VALUE_CHECKS))
    return cast(ValueCheck, VALUE_CHECKS[kind](node))


def build_nominal_value(node: ConfigNode) -> Check:
    node.check_keys(("type", "value", "deviation"))
    value_node = node.get("value")
    value = build_value_check(value_node) if value_node is not None else None
    deviation_node = node.get("deviation")
    entries = deviation_node.list(allow_single=True) if deviation_node is not None else []
    deviation = tuple(build_value_check(e) for e in entries if not e.is_null)
    if value is None and not deviation:
        return AcceptAllCheck("empty nominal_value check")
    return NominalValueCheck(value, deviation)


CHECKS.add(NOMINAL_VALUE, build_nominal_value, example={
    "type": NOMINAL_VALUE, "value": {"type": "gauss", "mean": 1.0, "std_deviation": 0.5},
    "deviation": {"type": "less_than", "less_than": 0.2}})
