"""Filters: streaming statistics over a window of samples, one module each, registered by
type name in :data:`~blackbox.observe.base.FILTERS` by that module.

``build_filter`` turns a configuration ``filter`` mapping into a filter; an absent, null
or empty mapping means ``nofilter``. Every filter reports the sample standard deviation
as its deviation unless the configuration asks for ``deviation: min_max``.
"""

from __future__ import annotations

from blackbox.config.node import ConfigNode
from blackbox.observe.base import FILTERS, Filter
from blackbox.observe.filters.ewma import EwmaFilter
from blackbox.observe.filters.kmeans import KMeansFilter
from blackbox.observe.filters.mean import MeanFilter
from blackbox.observe.filters.median import MedianFilter
from blackbox.observe.filters.nofilter import NoFilter
from blackbox.observe.filters.window import (
    DEVIATION_TYPES,
    MIN_MAX,
    STD_DEVIATION,
    SortedWindowFilter,
    Window,
    WindowFilter,
)

__all__ = [
    "DEVIATION_TYPES",
    "MIN_MAX",
    "STD_DEVIATION",
    "EwmaFilter",
    "KMeansFilter",
    "MeanFilter",
    "MedianFilter",
    "NoFilter",
    "SortedWindowFilter",
    "Window",
    "WindowFilter",
    "build_filter",
]


def build_filter(node: ConfigNode | None) -> Filter:
    """The filter a configuration ``filter`` mapping describes (``nofilter`` when empty)."""
    if node is None or node.is_null:
        return NoFilter()
    if not node.is_map:
        raise node.error("a filter is a mapping with a 'type', "
                         "for example {type: mean, window_size: 50}")
    if not node.keys():
        return NoFilter()
    kind = node["type"].str(sorted(FILTERS))
    return FILTERS[kind](node)
