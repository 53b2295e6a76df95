"""Value checks of the ``nominal_value`` check: one comparison of one number.

The comparisons are strict, as in the TU Graz tool: ``gauss`` passes when
``abs(x - mean) < std_deviation``, ``in_between`` when ``lower < x < upper``. A value
check also satisfies the :class:`~blackbox.observe.base.Check` protocol by testing the
summary's filtered value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol

from blackbox.config.node import ConfigNode
from blackbox.observe.base import Summary
from blackbox.observe.checks import params


class ValueCheck(Protocol):
    """A check on a single number (the filtered value or its deviation)."""

    def passes(self, x: float) -> bool: ...

    def test(self, summary: Summary) -> bool: ...

    def describe(self, subject: str = "value") -> str: ...


def _g(v: float) -> str:
    return f"{v:.12g}"


class _OnValue:
    """``Check.test`` for a value check: the check applied to the filtered value."""

    __slots__ = ()

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
    def from_config(cls, node: ConfigNode) -> GaussCheck:
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

    @classmethod
    def from_config(cls, node: ConfigNode) -> ExactCheck:
        node.check_keys(("type", "exact"))
        return cls(params.number(node, "exact"))

    def passes(self, x: float) -> bool:
        return x == self.exact

    def describe(self, subject: str = "value") -> str:
        return f"{subject} == {_g(self.exact)}"


@dataclass(frozen=True, slots=True)
class NotCheck(_OnValue):
    type_name: ClassVar[str] = "not"
    exact_not: float

    @classmethod
    def from_config(cls, node: ConfigNode) -> NotCheck:
        node.check_keys(("type", "exact_not"))
        return cls(params.number(node, "exact_not"))

    def passes(self, x: float) -> bool:
        return x != self.exact_not

    def describe(self, subject: str = "value") -> str:
        return f"{subject} != {_g(self.exact_not)}"


@dataclass(frozen=True, slots=True)
class GreaterThanCheck(_OnValue):
    type_name: ClassVar[str] = "greater_than"
    greater_than: float

    @classmethod
    def from_config(cls, node: ConfigNode) -> GreaterThanCheck:
        node.check_keys(("type", "greater_than"))
        return cls(params.number(node, "greater_than"))

    def passes(self, x: float) -> bool:
        return x > self.greater_than

    def describe(self, subject: str = "value") -> str:
        return f"{subject} > {_g(self.greater_than)}"


@dataclass(frozen=True, slots=True)
class LessThanCheck(_OnValue):
    type_name: ClassVar[str] = "less_than"
    less_than: float

    @classmethod
    def from_config(cls, node: ConfigNode) -> LessThanCheck:
        node.check_keys(("type", "less_than"))
        return cls(params.number(node, "less_than"))

    def passes(self, x: float) -> bool:
        return x < self.less_than

    def describe(self, subject: str = "value") -> str:
        return f"{subject} < {_g(self.less_than)}"


@dataclass(frozen=True, slots=True)
class InBetweenCheck(_OnValue):
    type_name: ClassVar[str] = "in_between"
    lower_bound: float
    upper_bound: float

    def __post_init__(self) -> None:
        if not self.lower_bound < self.upper_bound:
            raise ValueError("lower_bound must be < upper_bound")

    @classmethod
    def from_config(cls, node: ConfigNode) -> InBetweenCheck:
        node.check_keys(("type", "lower_bound", "upper_bound"))
        return cls(*params.bounds(node))

    def passes(self, x: float) -> bool:
        return self.lower_bound < x < self.upper_bound

    def describe(self, subject: str = "value") -> str:
        return f"{_g(self.lower_bound)} < {subject} < {_g(self.upper_bound)}"


@dataclass(frozen=True, slots=True)
class NotInBetweenCheck(_OnValue):
    type_name: ClassVar[str] = "not_in_between"
    lower_bound: float
    upper_bound: float

    def __post_init__(self) -> None:
        if not self.lower_bound < self.upper_bound:
            raise ValueError("lower_bound must be < upper_bound")

    @classmethod
    def from_config(cls, node: ConfigNode) -> NotInBetweenCheck:
        node.check_keys(("type", "lower_bound", "upper_bound"))
        return cls(*params.bounds(node))

    def passes(self, x: float) -> bool:
        return x < self.lower_bound or x > self.upper_bound

    def describe(self, subject: str = "value") -> str:
        return f"{subject} < {_g(self.lower_bound)} or {subject} > {_g(self.upper_bound)}"

