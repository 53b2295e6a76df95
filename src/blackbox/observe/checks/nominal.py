"""The ``nominal_value`` check: value checks on the filtered value and on its deviation.

A state fits when the optional ``value`` check passes on the filtered value and every
entry of the optional ``deviation`` list passes on the deviation. An undefined deviation
(the sample standard deviation of a single sample) passes no deviation check: a state that
constrains the spread cannot be confirmed before there is a spread. Without any value or
deviation check (template files leave both empty) the check accepts everything.
"""

from __future__ import annotations

from dataclasses import dataclass

from blackbox.observe.base import Summary
from blackbox.observe.checks.value import ValueCheck


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
