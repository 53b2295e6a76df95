"""Median filter: the median of the last ``window_size`` samples."""

from __future__ import annotations

from math import isfinite

from sortedcontainers import SortedList

from blackbox.config.node import ConfigNode
from blackbox.observe.filters import params
from blackbox.observe.filters.window import STD_DEVIATION, WindowFilter


class MedianFilter(WindowFilter):
    """The window is mirrored in a sorted list, so a sample costs O(log n), never a sort.

    For an even number of samples the median is the mean of the two middle values.
    """

    type_name = "median"
    __slots__ = ("_sorted",)

    def __init__(self, window_size: int, deviation: str = STD_DEVIATION) -> None:
        super().__init__(window_size, deviation)
        self._sorted: SortedList = SortedList()

    @classmethod
    def from_config(cls, node: ConfigNode) -> MedianFilter:
        node.check_keys(("type", "window_size", "deviation"))
        return cls(params.window_size(node), params.deviation_type(node))

    def update(self, x: float) -> None:
        if not isfinite(x):
            self.rejected += 1
            return
        evicted = self._window.push(x)
        if evicted is not None:
            self._sorted.remove(evicted)
        self._sorted.add(x)

    def get(self) -> float | None:
        s = self._sorted
        n = len(s)
        if not n:
            return None
        if self._window.constant:
            return s[0]
        mid = n // 2
        return s[mid] if n % 2 else (s[mid - 1] + s[mid]) / 2.0

    def reset(self) -> None:
        super().reset()
        self._sorted.clear()
