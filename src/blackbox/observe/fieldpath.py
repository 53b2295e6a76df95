"""Field paths into decoded messages: ``pose.position.x``, ``ranges[3]``, ``points[0].x``.

A path is compiled once at configuration time into a chain of small accessors, so reading
a field per message costs a few attribute or item look-ups. The same path works on every
shape a source may decode a message into: attribute objects (rosbags messages,
dataclasses, ``SimpleNamespace``), mappings (JSON-decoded messages) and sequences
(lists, tuples, numpy arrays).

A path that does not resolve on a given message raises :class:`ValueError` naming the
path and the step that failed, so an observer can report why a sample was skipped.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from numbers import Real
from typing import Any

_NAME = r"[A-Za-z_][A-Za-z0-9_]*"
_SEGMENT = re.compile(rf"({_NAME})((?:\[-?\d+\])*)")
_INDEX = re.compile(r"\[(-?\d+)\]")

_Step = tuple[bool, str | int]  # (is_index, attribute name or index)


def _parse(path: str) -> list[_Step]:
    if not isinstance(path, str) or not path.strip():
        raise ValueError("field path must be a non-empty string")
    steps: list[_Step] = []
    for segment in path.split("."):
        m = _SEGMENT.fullmatch(segment)
        if m is None:
            raise ValueError(
                f"invalid field path {path!r}: bad segment {segment!r} "
                "(expected name, name[i] or name[i][j], names joined by '.')")
        steps.append((False, m.group(1)))
        steps.extend((True, int(i)) for i in _INDEX.findall(m.group(2)))
    return steps


def _shown(steps: list[_Step], upto: int) -> str:
    out = ""
    for is_index, key in steps[:upto]:
        out += f"[{key}]" if is_index else (f".{key}" if out else str(key))
    return out or "message"


def describe_value(value: Any) -> str:
    """A value's type and its repr cut to 40 characters, for error messages."""
    text = repr(value)
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{type(value).__name__} {text}"


def compile_field_access(path: str) -> Callable[[Any], Any]:
    """Compile ``path`` into a function returning the raw value at that path.

    Raises :class:`ValueError` at compile time for a malformed path and at call time for
    a path that does not resolve on the given message.
    """
    steps = _parse(path)
    mapping: dict[type, bool] = {}  # per type: a Mapping? (an ABC check costs a microsecond)

    def access(message: Any) -> Any:
        value = message
        for n, (is_index, key) in enumerate(steps):
            try:
                kind = type(value)
                by_item = mapping.get(kind)
                if by_item is None:
                    by_item = mapping[kind] = isinstance(value, Mapping)
                value = (value[key] if is_index or by_item
                         else getattr(value, key))  # type: ignore[arg-type]
            except (AttributeError, KeyError):
                raise ValueError(f"field path {path!r}: {_shown(steps, n)} has no field "
                                 f"{key!r}") from None
            except IndexError:
                raise ValueError(f"field path {path!r}: index {key} out of range for "
                                 f"{_shown(steps, n)}") from None
            except (TypeError, ValueError):
                raise ValueError(f"field path {path!r}: {_shown(steps, n)} is "
                                 f"{describe_value(value)}, cannot take [{key}]") from None
        return value

    return access


def compile_field_path(path: str) -> Callable[[Any], float]:
    """Compile ``path`` into a function returning the number at that path as a float.

    Integers, floats, booleans (as 0 and 1) and numpy scalars count as numbers; strings do
    not, even when they look like one. Non-finite values are returned as they are: whether
    NaN is a fault is the observer's decision.
    """
    access = compile_field_access(path)

    def number(message: Any) -> float:
        value = access(message)
        if isinstance(value, Real):
            return float(value)
        # numpy scalars of other kinds and 0-d arrays
        if getattr(value, "ndim", None) == 0 and getattr(value, "dtype", None) is not None:
            kind = value.dtype.kind
            if kind in "biuf":
                return float(value)
        raise ValueError(f"field path {path!r}: value is {describe_value(value)}, not a number")

    return number
