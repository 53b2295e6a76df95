"""Median filter: the median of the last ``window_size`` samples."""

from __future__ import annotations

from blackbox.config.node import ConfigNode
from blackbox.observe.base import FILTERS
from blackbox.observe.filters import params
from blackbox.observe.filters.window import SortedWindowFilter


class MedianFilter(SortedWindowFilter):
    """O(log n) per sample and per ``get``.

    For an even number of samples the median is the mean of the two middle values.
    """

    type_name = "median"
    __slots__ = ()

    @classmethod
    def from_config(cls, node: ConfigNode) -> MedianFilter:
        node.check_keys(("type", "window_size", "deviation"))
        return cls(params.window_size(node), params.deviation_type(node))

    def get(self) -> float | None:
        s = self._sorted
        n = len(s)
        if not n:
            return None
        median: float
        if self._window.constant:
            median = s[0]
        else:
            mid = n // 2
            median = s[mid] if n % 2 else (s[mid - 1] + s[mid]) / 2.0
        return median


FILTERS.add(MedianFilter.type_name, MedianFilter.from_config,
            example={"type": "median", "window_size": 5, "deviation": "min_max"})
