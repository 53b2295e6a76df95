"""Hypothesis checks: does a filtered summary fit a state?

A quantity's check in a state is either ``student_t`` or ``nominal_value`` (the default
when ``value`` or ``deviation`` is given). The value checks of ``nominal_value`` (gauss,
exact, not, greater_than, less_than, in_between, not_in_between) are registered by name in
:data:`~blackbox.observe.base.VALUE_CHECKS` by their module (the check types ``student_t``
and ``nominal_value`` in :data:`~blackbox.observe.base.CHECKS`); a registered value check
must also provide ``passes(x) -> bool`` and ``describe(subject)`` (see :class:`ValueCheck`).

An absent, null or empty check accepts every summary, as do ``nominal_value`` checks
whose ``value`` and ``deviation`` are both empty (tug template files).
"""

from __future__ import annotations

from blackbox.config.node import ConfigNode
from blackbox.observe.base import CHECKS, VALUE_CHECKS, Check
from blackbox.observe.checks.nominal import (
    NOMINAL_VALUE,
    AcceptAllCheck,
    NominalValueCheck,
    build_nominal_value,
    build_value_check,
)
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
    "NOMINAL_VALUE",
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
    kind = type_node.str(list(CHECKS))
    return CHECKS[kind](node)
