"""Value checks of the ``nominal_value`` check: one comparison of one number.

The comparisons are strict, as in the TU Graz tool: ``gauss`` passes when
``abs(x - mean) < std_deviation``, ``in_between`` when ``lower < x < upper``. A value
check also satisfies the :class:`~blackbox.observe.base.Check` protocol by testing the
summary's filtered value.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, ClassVar, Protocol, Self, cast

from blackbox.config.node import ConfigNode
from blackbox.observe.base import VALUE_CHECKS, Summary
from blackbox.observe.checks import params

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


class ValueCheck(Protocol):
    """A check on a single number (the filtered value or its deviation)."""

    def passes(self, x: float) -> bool: ...

    def test(self, summary: Summary) -> bool: ...

    def describe(self, subject: str = "value") -> str: ...


def _g(v: float) -> str:
    return f"{v:.12g}"


class _OnValue:
    """``Check.test`` for a value check: the check applied to the filtered value.

    Also reads a value check from configuration: each of its dataclass fields is a finite
    number under its own name. A check whose numbers need more (a positive width, ordered
    bounds) overrides ``from_config``.
    """

    __slots__ = ()

    @classmethod
    def from_config(cls, node: ConfigNode) -> Self:
        names = tuple(f.name for f in fields(cast("type[DataclassInstance]", cls)))
        node.check_keys(("type", *names))
        return cls(*(params.number(node, name) for name in names))

    def passes(self, x: float) -> bool:
        raise NotImplementedError

    def test(self, summary: Summary) -> bool:
        return self.passes(summary.value)


@dataclass(frozen=True, slots=True)
class GaussCheck(_OnValue):
    type_name: ClassVar[str] = "gauss"
    mean: float
    std_deviation: float

    def __post_init__(self) -> None:
        if not self.std_deviation > 0.0:
            raise ValueError(f"std_deviation must be > 0, got {self.std_deviation}")

    @classmethod
    def from_config(cls, node: ConfigNode) -> Self:
        node.check_keys(("type", "mean", "std_deviation"))
        return cls(params.number(node, "mean"), params.positive(node, "std_deviation"))

    def passes(self, x: float) -> bool:
        return abs(x - self.mean) < self.std_deviation

    def describe(self, subject: str = "value") -> str:
        return f"|{subject} - {_g(self.mean)}| < {_g(self.std_deviation)}"


@dataclass(frozen=True, slots=True)
class ExactCheck(_OnValue):
    type_name: ClassVar[str] = "exact"
    exact: float

    def passes(self, x: float) -> bool:
        return x == self.exact

    def describe(self, subject: str = "value") -> str:
        return f"{subject} == {_g(self.exact)}"


@dataclass(frozen=True, slots=True)
class NotCheck(_OnValue):
    type_name: ClassVar[str] = "not"
    exact_not: float

    def passes(self, x: float) -> bool:
        return x != self.exact_not

    def describe(self, subject: str = "value") -> str:
        return f"{subject} != {_g(self.exact_not)}"


@dataclass(frozen=True, slots=True)
class GreaterThanCheck(_OnValue):
    type_name: ClassVar[str] = "greater_than"
    greater_than: float

    def passes(self, x: float) -> bool:
        return x > self.greater_than

    def describe(self, subject: str = "value") -> str:
        return f"{subject} > {_g(self.greater_than)}"


@dataclass(frozen=True, slots=True)
class LessThanCheck(_OnValue):
    type_name: ClassVar[str] = "less_than"
    less_than: float

    def passes(self, x: float) -> bool:
        return x < self.less_than

    def describe(self, subject: str = "value") -> str:
        return f"{subject} < {_g(self.less_than)}"


@dataclass(frozen=True, slots=True)
class _Interval(_OnValue):
    """The two bounds of an interval check, ``lower_bound < upper_bound``."""

    lower_bound: float
    upper_bound: float

    def __post_init__(self) -> None:
        if not self.lower_bound < self.upper_bound:
            raise ValueError("lower_bound must be < upper_bound")

    @classmethod
    def from_config(cls, node: ConfigNode) -> Self:
        node.check_keys(("type", "lower_bound", "upper_bound"))
        return cls(*params.bounds(node))


@dataclass(frozen=True, slots=True)
class InBetweenCheck(_Interval):
    type_name: ClassVar[str] = "in_between"

    def passes(self, x: float) -> bool:
        return self.lower_bound < x < self.upper_bound

    def describe(self, subject: str = "value") -> str:
        return f"{_g(self.lower_bound)} < {subject} < {_g(self.upper_bound)}"


@dataclass(frozen=True, slots=True)
class NotInBetweenCheck(_Interval):
    type_name: ClassVar[str] = "not_in_between"

    def passes(self, x: float) -> bool:
        return x < self.lower_bound or x > self.upper_bound

    def describe(self, subject: str = "value") -> str:
        return f"{subject} < {_g(self.lower_bound)} or {subject} > {_g(self.upper_bound)}"


_EXAMPLE_NUMBERS: dict[str, dict[str, float]] = {
    "gauss": {"mean": 1.0, "std_deviation": 0.5},
    "exact": {"exact": 1.0},
    "not": {"exact_not": 0.0},
    "greater_than": {"greater_than": 0.5},
    "less_than": {"less_than": 1.5},
    "in_between": {"lower_bound": 0.5, "upper_bound": 1.5},
    "not_in_between": {"lower_bound": 2.0, "upper_bound": 3.0},
}
for _check in (GaussCheck, ExactCheck, NotCheck, GreaterThanCheck, LessThanCheck, InBetweenCheck,
               NotInBetweenCheck):
    VALUE_CHECKS.add(_check.type_name, _check.from_config,
                     example={"type": _check.type_name, **_EXAMPLE_NUMBERS[_check.type_name]})
