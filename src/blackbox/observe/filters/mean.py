"""Mean filter: the arithmetic mean of the last ``window_size`` samples."""

from __future__ import annotations

from blackbox.config.node import ConfigNode
from blackbox.observe.base import FILTERS
from blackbox.observe.filters import params
from blackbox.observe.filters.window import STD_DEVIATION, WindowFilter


class MeanFilter(WindowFilter):
    """O(1) per sample: the window keeps a drift-corrected running mean."""

    type_name = "mean"
    __slots__ = ()

    def __init__(self, window_size: int, deviation: str = STD_DEVIATION) -> None:
        super().__init__(window_size, deviation)

    @classmethod
    def from_config(cls, node: ConfigNode) -> MeanFilter:
        node.check_keys(("type", "window_size", "deviation"))
        return cls(params.window_size(node), params.deviation_type(node))

    def get(self) -> float | None:
        return self._window.mean()


FILTERS.add(MeanFilter.type_name, MeanFilter.from_config,
            example={"type": "mean", "window_size": 5})
