"""Reading filter parameters from configuration, with one clear message per mistake."""

from __future__ import annotations

from blackbox.config.node import ConfigNode
from blackbox.observe.filters.window import DEVIATION_TYPES, STD_DEVIATION


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _positive_int(child: ConfigNode, key: str) -> int:
    v = child.raw
    if not _is_number(v) or (isinstance(v, float) and not v.is_integer()) or v < 1:
        raise child.error(f"{key} must be an integer >= 1, got {v!r}")
    return int(v)


def window_size(node: ConfigNode) -> int:
    """``window_size`` (required): an integer >= 1."""
    return _positive_int(node["window_size"], "window_size")


def optional_window_size(node: ConfigNode) -> int | None:
    """``window_size`` (optional): an integer >= 1, ``None`` when absent."""
    child = node.get("window_size")
    return None if child is None else _positive_int(child, "window_size")


def k_size(node: ConfigNode, window: int) -> int:
    """``k_size``: an integer with 1 <= k_size <= window_size."""
    child = node["k_size"]
    k = _positive_int(child, "k_size")
    if k > window:
        raise child.error(f"k_size must be <= window_size ({window}), got {k}")
    return k


def decay_rate(node: ConfigNode) -> float:
    """``decay_rate``: the weight of a new sample, 0 < d <= 1."""
    child = node["decay_rate"]
    v = child.raw
    if not _is_number(v) or not 0.0 < float(v) <= 1.0:
        raise child.error(f"decay_rate must be a number in (0, 1], got {v!r}")
    return float(v)


def deviation_type(node: ConfigNode) -> str:
    """``deviation``: ``std_deviation`` (the default) or ``min_max``."""
    child = node.get("deviation")
    return STD_DEVIATION if child is None else child.str(DEVIATION_TYPES)
