"""One numeric signal of a topic, sampled on a regular grid, and a two-sided CUSUM.

Learned relations (``relation``) and per-signal liveness (``liveness``) read single numbers
out of messages: a scalar field (``twist.twist.linear.x``) or one element of a numeric
array (``velocity[1]``). Topics arrive at different rates and at irregular times, so a
relation compares them on a common grid of ``step`` seconds: the grid value of a signal is
the mean of its samples in the cell ``(g - step, g]``, or the last value when the cell is
empty and the last sample is younger than ``fresh`` seconds; older, the signal is *stale*
and the grid value is NaN (no verdict is made on it).

Everything is pure: time is passed in, nothing reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from numbers import Real
from typing import Any

from blackbox.config.node import ConfigNode
from blackbox.observe.fieldpath import compile_field_access

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class SignalRef:
    """A number in the messages of a topic: ``field`` is a path (``ranges[3]`` allowed)."""

    topic: str
    field: str

    def label(self) -> str:
        return f"{self.topic} {self.field}"


def read_signal_ref(node: ConfigNode) -> SignalRef:
    """``{topic: /odom, field: twist.twist.linear.x}``."""
    node.check_keys(("topic", "field"))
    field_node = node["field"]
    path = field_node.str()
    try:
        compile_field_access(path)
    except ValueError as exc:
        raise field_node.error(str(exc)) from None
    topic = node["topic"].str()
    if not topic.strip():
        raise node["topic"].error("topic must be a name")
    return SignalRef(topic, path)


def number_of(value: Any) -> float | None:
    """``value`` as a float, ``None`` when it is not a real number (bools are not)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, Real):
        return float(value)
    if getattr(value, "ndim", None) == 0 and getattr(value, "dtype", None) is not None \
            and value.dtype.kind in "iuf":
        return float(value)
    return None


class SignalReader:
    """Reads one signal from decoded messages; counts what could not be read, and why."""

    __slots__ = ("_access", "last_problem", "non_finite", "ref", "unreadable")

    def __init__(self, ref: SignalRef) -> None:
        self.ref = ref
        self._access: Callable[[Any], Any] = compile_field_access(ref.field)
        self.unreadable = 0
        self.non_finite = 0
        self.last_problem = ""

    def read(self, message: Any) -> float | None:
        """The finite number at the field, or ``None`` (counted) when there is none."""
        try:
            x = number_of(self._access(message))
        except ValueError as exc:
            self.unreadable += 1
            self.last_problem = str(exc)
            return None
        if x is None:
            self.unreadable += 1
            self.last_problem = f"{self.ref.field} is not a number"
            return None
        if not math.isfinite(x):
            self.non_finite += 1
            self.last_problem = f"{self.ref.field} is {x}"
            return None
        return x


class GridCell:
    """The grid value of one signal: mean of the samples of the current cell, else the held
    value while it is fresh."""

    __slots__ = ("_count", "_sum", "fresh", "held", "last_time")

    def __init__(self, fresh: float) -> None:
        self.fresh = fresh
        self._sum = 0.0
        self._count = 0
        self.held = math.nan
        self.last_time = -math.inf

    def add(self, t: float, x: float) -> None:
        self._sum += x
        self._count += 1
        self.last_time = t

    def close(self, g: float) -> float:
        """The value at grid time ``g`` (ending the cell ``(g - step, g]``)."""
        if self._count:
            self.held = self._sum / self._count
            self._sum = 0.0
            self._count = 0
            return self.held
        if g - self.last_time > self.fresh:
            return math.nan
        return self.held

    def reset(self) -> None:
        self._sum = 0.0
        self._count = 0
        self.held = math.nan
        self.last_time = -math.inf


def wrapped_difference(a: float, b: float) -> float:
    """``a - b`` for angles: the shortest way round, in ``(-pi, pi]``."""
    d = math.fmod(a - b, TWO_PI)
    if d > math.pi:
        d -= TWO_PI
    elif d <= -math.pi:
        d += TWO_PI
    return d


@dataclass(frozen=True, slots=True)
class CusumSpec:
    """Page's CUSUM on standardised block statistics: drift ``k`` (half the shift it is
    tuned for, in noise units), alarm at ``h``. ``h`` is calibrated while learning for a
    stated false-alarm rate (docs/learn.md)."""

    k: float
    h: float

    @classmethod
    def read(cls, node: ConfigNode) -> CusumSpec:
        node.check_keys(("k", "h"))
        return cls(node["k"].float(min=0.0), node["h"].float(min=0.0, min_exclusive=True))


class Cusum:
    """Two-sided (or upward only) CUSUM with a ceiling, so an alarm ends soon after the
    fault: the statistic stays at most ``ceiling`` drifts above ``h`` and falls by ``k`` per
    healthy block."""

    __slots__ = ("down", "spec", "top", "two_sided", "up")

    def __init__(self, spec: CusumSpec, two_sided: bool = True, ceiling: float = 4.0) -> None:
        self.spec = spec
        self.two_sided = two_sided
        self.top = spec.h + ceiling * max(spec.k, 0.25)
        self.up = 0.0
        self.down = 0.0

    def update(self, z: float) -> float:
        k, top = self.spec.k, self.top
        self.up = min(top, max(0.0, self.up + z - k))
        if self.two_sided:
            self.down = min(top, max(0.0, self.down - z - k))
        return self.statistic

    @property
    def statistic(self) -> float:
        return max(self.up, self.down)

    @property
    def alarm(self) -> bool:
        return self.statistic >= self.spec.h

    def reset(self) -> None:
        self.up = 0.0
        self.down = 0.0
