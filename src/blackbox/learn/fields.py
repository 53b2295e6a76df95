"""Finding the numeric fields of a topic, and telling what kind of number each one is.

Fields are found by walking the message definition as the source decoded it (rosbags
builds each message from the publisher's ``message_definition``, so its nested fields are
that definition's fields): numeric scalars become one quantity each, numeric arrays
(fixed or variable length, byte arrays included) become summary quantities (mean, min,
max, fraction in range), nested messages are walked, and a ``header.stamp`` (any time
struct with ``sec``/``nanosec`` or ``secs``/``nsecs``) is a time stamp: it feeds the
message-age observer, never a value observer. Strings, arrays of messages and other
non-numbers are skipped and listed.

After the run each recorded series is classified (``classify``): constant, counter,
monotonic (a clock or an odometer), discrete (a few integer levels: modes, flags), or
numeric (noisy measurements: these get bounds).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any, Literal

import numpy as np

MAX_DEPTH = 6
MAX_FIELDS = 48
"""At most this many numeric fields per topic are followed (the rest are listed)."""
DISCRETE_LEVELS = 5

FieldKind = Literal["scalar", "array", "stamp"]
SeriesKind = Literal["constant", "counter", "monotonic", "discrete", "numeric"]


@dataclass(frozen=True, slots=True)
class FieldInfo:
    path: str
    kind: FieldKind
    integer: bool = False


@dataclass(frozen=True, slots=True)
class Discovery:
    fields: tuple[FieldInfo, ...]
    skipped: tuple[str, ...]
    """Field paths that are not numbers (strings, arrays of messages), with the reason."""


def _is_time(value: Any) -> bool:
    for sec, nsec in (("sec", "nanosec"), ("secs", "nsecs")):
        if isinstance(_get(value, sec), Integral) and isinstance(_get(value, nsec), Integral):
            return True
    return False


def _get(value: Any, name: str) -> Any:
    if isinstance(value, Mapping):
        return value.get(name)
    return getattr(value, name, None)


def _children(value: Any) -> Iterator[tuple[str, Any]] | None:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return ((f.name, getattr(value, f.name)) for f in dataclasses.fields(value))
    if isinstance(value, Mapping):
        return ((str(k), v) for k, v in value.items())
    slots = getattr(type(value), "__slots__", None)
    if slots and not isinstance(value, (str, bytes)):
        return ((s, getattr(value, s)) for s in slots if not s.startswith("_"))
    return None


def discover(message: Any) -> Discovery:
    """The numeric fields of ``message`` (a decoded message of any shape)."""
    found: list[FieldInfo] = []
    skipped: list[str] = []

    def walk(value: Any, path: str, depth: int) -> None:
        if _is_time(value):
            found.append(FieldInfo(path, "stamp"))
            return
        if isinstance(value, bool):
            found.append(FieldInfo(path, "scalar", True))
            return
        if isinstance(value, Real):
            found.append(FieldInfo(path, "scalar", isinstance(value, Integral)))
            return
        if isinstance(value, np.generic) and value.dtype.kind in "biuf":
            found.append(FieldInfo(path, "scalar", value.dtype.kind in "biu"))
            return
        if isinstance(value, (bytes, bytearray)):
            if value:
                found.append(FieldInfo(path, "array", True))
            else:
                skipped.append(f"{path} (empty array)")
            return
        if isinstance(value, np.ndarray):
            if value.size == 0:
                skipped.append(f"{path} (empty array)")
            elif value.dtype.kind in "biuf":
                found.append(FieldInfo(path, "array", value.dtype.kind in "biu"))
            else:
                skipped.append(f"{path} (array of {value.dtype})")
            return
        if isinstance(value, (list, tuple)):
            if value and all(isinstance(v, Real) for v in value):
                found.append(FieldInfo(path, "array", all(isinstance(v, Integral)
                                                          for v in value)))
            elif not value:
                skipped.append(f"{path} (empty array)")
            else:
                skipped.append(f"{path} (array of messages)")
            return
        if isinstance(value, str):
            return  # strings (frame ids, encodings) are names, not measurements
        children = _children(value)
        if children is None or depth >= MAX_DEPTH:
            skipped.append(f"{path or 'message'} ({type(value).__name__})")
            return
        for name, child in children:
            walk(child, f"{path}.{name}" if path else name, depth + 1)

    walk(message, "", 0)
    if len(found) > MAX_FIELDS:
        skipped.extend(f"{f.path} (more than {MAX_FIELDS} numeric fields)"
                       for f in found[MAX_FIELDS:])
        found = found[:MAX_FIELDS]
    return Discovery(tuple(found), tuple(skipped))


@dataclass(frozen=True, slots=True)
class SeriesClass:
    kind: SeriesKind
    note: str


def classify(samples: np.ndarray, integer: bool) -> SeriesClass:
    """What kind of number a recorded series is (module docstring)."""
    x = samples[np.isfinite(samples)]
    if x.size == 0:
        return SeriesClass("constant", "no finite value")
    lo, hi = float(x.min()), float(x.max())
    if lo == hi:
        return SeriesClass("constant", f"always {_num(lo)}")
    if x.size >= 3:
        steps = np.diff(x)
        if np.all(steps >= 0) or np.all(steps <= 0):
            positive = steps[steps != 0]
            if integer and positive.size and np.all(positive == positive[0]) \
                    and positive.size >= 0.9 * steps.size:
                return SeriesClass("counter", f"counts by {_num(float(positive[0]))} per "
                                   f"message ({_num(float(x[0]))} to {_num(float(x[-1]))})")
            return SeriesClass("monotonic", f"only {'grows' if steps.sum() > 0 else 'falls'} "
                               f"({_num(float(x[0]))} to {_num(float(x[-1]))}): a clock, "
                               "counter or odometer")
    levels = np.unique(x)
    if (integer or np.all(levels == np.round(levels))) and levels.size <= DISCRETE_LEVELS:
        return SeriesClass("discrete", "takes the values "
                           + ", ".join(_num(float(v)) for v in levels))
    return SeriesClass("numeric", "")


def _num(x: float) -> str:
    return f"{x:.6g}"
