"""Hypothesis checks: does a filtered summary fit a state?

A quantity's check in a state is either ``student_t`` or ``nominal_value`` (the default
when ``value`` or ``deviation`` is given). The value checks of ``nominal_value`` (gauss,
exact, not, greater_than, less_than, in_between, not_in_between) are registered by name in
:data:`~blackbox.observe.base.VALUE_CHECKS`; a registered value check must also provide
``passes(x) -> bool`` and ``describe(subject)`` (see :class:`ValueCheck`).

An absent, null or empty check accepts every summary, as do ``nominal_value`` checks
whose ``value`` and ``deviation`` are both empty (tug template files).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import cast

from blackbox.config.node import ConfigNode
from blackbox.observe.base import VALUE_CHECKS, Check, register
from blackbox.observe.checks.nominal import AcceptAllCheck, NominalValueCheck
from blackbox.observe.checks.student_t import StudentTCheck
from blackbox.observe.checks.value import (
    ExactCheck,
    GaussCheck,
    GreaterThanCheck,
    InBetweenCheck,
    LessThanCheck,
    NotCheck,
    NotInBetweenCheck,
    ValueCheck,
)

__all__ = [
    "CHECK_TYPES",
    "AcceptAllCheck",
    "ExactCheck",
    "GaussCheck",
    "GreaterThanCheck",
    "InBetweenCheck",
    "LessThanCheck",
    "NominalValueCheck",
    "NotCheck",
    "NotInBetweenCheck",
    "StudentTCheck",
    "ValueCheck",
    "build_check",
    "build_value_check",
]

register(VALUE_CHECKS, GaussCheck.type_name)(GaussCheck.from_config)
register(VALUE_CHECKS, ExactCheck.type_name)(ExactCheck.from_config)
register(VALUE_CHECKS, NotCheck.type_name)(NotCheck.from_config)
register(VALUE_CHECKS, GreaterThanCheck.type_name)(GreaterThanCheck.from_config)
register(VALUE_CHECKS, LessThanCheck.type_name)(LessThanCheck.from_config)
register(VALUE_CHECKS, InBetweenCheck.type_name)(InBetweenCheck.from_config)
register(VALUE_CHECKS, NotInBetweenCheck.type_name)(NotInBetweenCheck.from_config)

NOMINAL_VALUE = "nominal_value"


def build_value_check(node: ConfigNode) -> ValueCheck:
    """One value check from a mapping with ``type`` and that type's parameters."""
    if not node.is_map:
        raise node.error("a value check is a mapping with a 'type', "
                         "for example {type: gauss, mean: 15.0, std_deviation: 0.5}")
    kind = node["type"].str(sorted(VALUE_CHECKS))
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


CHECK_TYPES: Mapping[str, Callable[[ConfigNode], Check]] = MappingProxyType({
    StudentTCheck.type_name: StudentTCheck.from_config,
    NOMINAL_VALUE: build_nominal_value,
})


def build_check(node: ConfigNode | None) -> Check:
    """The check a state's quantity entry describes; empty means accept everything."""
    if node is None or node.is_null:
        return AcceptAllCheck("empty check")
    if not node.is_map:
        raise node.error("a check is a mapping, for example {type: student_t, true_mean: 0.1, "
                         "significance_level: 0.05} or {value: {type: gauss, mean: 0.1, "
                         "std_deviation: 0.01}}")
    if not node.keys():
        return AcceptAllCheck("empty check")
    type_node = node.get("type")
    if type_node is None:
        if "value" in node or "deviation" in node:
            return build_nominal_value(node)
        node.check_keys(("type", "value", "deviation", "true_mean", "significance_level",
                         "std_deviation"))
        raise node.error("missing required key 'type' (student_t or nominal_value)")
    raw = type_node.raw
    if isinstance(raw, str) and raw in VALUE_CHECKS:
        raise type_node.error(
            f"{raw!r} is a value check; put it under 'value:' of a nominal_value check, "
            f"for example value: {{type: {raw}, ...}}")
    kind = type_node.str(CHECK_TYPES)
    return CHECK_TYPES[kind](node)
