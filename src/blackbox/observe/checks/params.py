"""Reading check parameters from configuration, with one clear message per mistake."""

from __future__ import annotations

import math

from blackbox.config.node import ConfigNode


def number(node: ConfigNode, key: str) -> float:
    """The finite number at ``key`` (required)."""
    child = node[key]
    v = child.raw
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise child.error(f"{key} must be a finite number, got {v!r}")
    return float(v)


def positive(node: ConfigNode, key: str) -> float:
    """The number at ``key``, which must be > 0."""
    v = number(node, key)
    if v <= 0.0:
        raise node[key].error(f"{key} must be > 0, got {v:g}")
    return v


def probability(node: ConfigNode, key: str) -> float:
    """The number at ``key``, which must lie strictly between 0 and 1."""
    v = number(node, key)
    if not 0.0 < v < 1.0:
        raise node[key].error(f"{key} must be between 0 and 1 (exclusive), got {v:g}")
    return v


def bounds(node: ConfigNode) -> tuple[float, float]:
    """``lower_bound`` and ``upper_bound`` with ``lower_bound < upper_bound``."""
    lower, upper = number(node, "lower_bound"), number(node, "upper_bound")
    if not lower < upper:
        raise node["upper_bound"].error(
            f"upper_bound ({upper:g}) must be greater than lower_bound ({lower:g})")
    return lower, upper
