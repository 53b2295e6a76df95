"""K-means filter of the TU Graz tool: the mean of the ``k_size`` central sorted samples.

Not the clustering algorithm: a trimmed mean. The window is sorted, the ``k_size`` values in
its middle are averaged, so up to ``(window_size - k_size) / 2`` outliers on either side are
ignored. When ``n - k`` is odd the central block starts at ``(n - k) // 2`` (one more value
is trimmed from the top than from the bottom). While the window holds fewer than ``k_size``
samples, all of them are averaged.
"""

from __future__ import annotations

from math import fsum

from blackbox.config.node import ConfigNode
from blackbox.observe.base import FILTERS
from blackbox.observe.filters import params
from blackbox.observe.filters.window import STD_DEVIATION, SortedWindowFilter


class KMeansFilter(SortedWindowFilter):
    """O(log n) per sample, O(k) per ``get``."""

    type_name = "kmeans"
    __slots__ = ("k_size",)

    def __init__(self, window_size: int, k_size: int, deviation: str = STD_DEVIATION) -> None:
        if not 1 <= k_size <= window_size:
            raise ValueError(f"k_size must be in [1, window_size], got {k_size}")
        super().__init__(window_size, deviation)
        self.k_size = k_size

    @classmethod
    def from_config(cls, node: ConfigNode) -> KMeansFilter:
        node.check_keys(("type", "window_size", "k_size", "deviation"))
        size = params.window_size(node)
        return cls(size, params.k_size(node, size), params.deviation_type(node))

    def get(self) -> float | None:
        s = self._sorted
        n = len(s)
        if not n:
            return None
        if self._window.constant:
            first: float = s[0]
            return first
        k = min(self.k_size, n)
        start = (n - k) // 2
        return fsum(s.islice(start, start + k)) / k

    def describe(self) -> str:
        return f"kmeans (central {self.k_size} of {self._describe_window()})"


FILTERS.add(KMeansFilter.type_name, KMeansFilter.from_config,
            example={"type": "kmeans", "window_size": 9, "k_size": 3})
