"""The Prometheus text exposition format (version 0.0.4), written by hand: a few gauges and
counters do not need a client library, and both the station's ``/metrics`` and
``blackbox run --metrics`` write the same format through :class:`MetricsText`."""

from __future__ import annotations

import math
from collections.abc import Mapping

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


def _label(value: str) -> str:
    return value.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def _number(value: float) -> str:
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    return repr(float(value)) if not float(value).is_integer() else str(int(value))


class MetricsText:
    """Families in the order added, each with its ``# HELP`` and ``# TYPE`` once."""

    def __init__(self) -> None:
        self._lines: list[str] = []
        self._seen: set[str] = set()

    def family(self, name: str, kind: str, help_text: str) -> None:
        if name not in self._seen:
            self._seen.add(name)
            self._lines.append(f"# HELP {name} {help_text}")
            self._lines.append(f"# TYPE {name} {kind}")

    def sample(self, name: str, value: float, labels: Mapping[str, str] | None = None) -> None:
        text = ",".join(f'{k}="{_label(v)}"' for k, v in (labels or {}).items())
        self._lines.append(f"{name}{{{text}}} {_number(value)}" if text
                           else f"{name} {_number(value)}")

    def add(self, name: str, kind: str, help_text: str, value: float,
            labels: Mapping[str, str] | None = None) -> None:
        self.family(name, kind, help_text)
        self.sample(name, value, labels)

    def render(self) -> str:
        return "\n".join(self._lines) + "\n"
