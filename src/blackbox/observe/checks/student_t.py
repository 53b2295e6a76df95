"""The ``student_t`` check: a two-sided one-sample t-test of the filtered value.

With n = the summary's sample count and s = the fixed ``std_deviation`` (when configured)
or the summary's deviation, t = (value - true_mean) / (s / sqrt(n)). The state fits when
the test does not reject: |t| <= t_{1 - a/2, n - 1}.

Edge cases, decided so that a state is never confirmed without evidence:

* n < 2: the t distribution has no degrees of freedom; the state does not fit (also with
  a fixed ``std_deviation``).
* deviation undefined (``None``) and no fixed ``std_deviation``: does not fit.
* s == 0 (constant window): fits exactly when the value equals ``true_mean``.

The deviation must be a standard deviation: pair this check with a filter using
``deviation: std_deviation`` (the default) or give a fixed ``std_deviation``; a ``min_max``
spread would be used as if it were one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import sqrt
from typing import ClassVar

from blackbox.config.node import ConfigNode
from blackbox.observe.base import CHECKS, Summary
from blackbox.observe.checks import params

_CACHE_LIMIT = 4096


def _t_quantile(p: float, df: int) -> float:
    # scipy.stats takes about half a second to import; only pay for it when a t-test runs.
    from scipy.stats import t

    return float(t.ppf(p, df))


@dataclass(slots=True)
class StudentTCheck:
    type_name: ClassVar[str] = "student_t"
    true_mean: float
    significance_level: float
    std_deviation: float | None = None
    _critical: dict[int, float] = field(default_factory=dict, init=False, repr=False,
                                        compare=False)

    def __post_init__(self) -> None:
        if not 0.0 < self.significance_level < 1.0:
            raise ValueError(f"significance_level must be in (0, 1), got "
                             f"{self.significance_level}")
        if self.std_deviation is not None and not self.std_deviation > 0.0:
            raise ValueError(f"std_deviation must be > 0, got {self.std_deviation}")

    @classmethod
    def from_config(cls, node: ConfigNode) -> StudentTCheck:
        node.check_keys(("type", "true_mean", "significance_level", "std_deviation"))
        fixed = None
        if node.get("std_deviation") is not None:
            fixed = params.positive(node, "std_deviation")
        return cls(params.number(node, "true_mean"),
                   params.probability(node, "significance_level"), fixed)

    def critical_value(self, n: int) -> float:
        """t_{1 - a/2, n - 1}, computed once per sample count."""
        crit = self._critical.get(n)
        if crit is None:
            if len(self._critical) >= _CACHE_LIMIT:
                self._critical.clear()
            crit = _t_quantile(1.0 - self.significance_level / 2.0, n - 1)
            self._critical[n] = crit
        return crit

    def statistic(self, summary: Summary) -> float | None:
        """The t statistic; ``None`` when undecidable (n < 2, no deviation, or s == 0)."""
        s = self.std_deviation if self.std_deviation is not None else summary.deviation
        if summary.count < 2 or not s:
            return None
        return (summary.value - self.true_mean) / (s / sqrt(summary.count))

    def test(self, summary: Summary) -> bool:
        n = summary.count
        if n < 2:
            return False
        s = self.std_deviation if self.std_deviation is not None else summary.deviation
        if s is None:
            return False
        diff = summary.value - self.true_mean
        if s == 0.0:
            return diff == 0.0
        return abs(diff) * sqrt(n) / s <= self.critical_value(n)

    def describe(self) -> str:
        std = (f"fixed std_deviation {self.std_deviation:.12g}"
               if self.std_deviation is not None else "window std_deviation")
        return (f"student_t: mean {self.true_mean:.12g} not rejected at significance "
                f"{self.significance_level:.12g} ({std})")


CHECKS.add(StudentTCheck.type_name, StudentTCheck.from_config,
           example={"type": "student_t", "true_mean": 1.0, "significance_level": 0.05})
