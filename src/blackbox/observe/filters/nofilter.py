"""No filter: the latest sample; the deviation covers all samples so far."""

from __future__ import annotations

from blackbox.config.node import ConfigNode
from blackbox.observe.base import FILTERS
from blackbox.observe.filters import params
from blackbox.observe.filters.window import STD_DEVIATION, WindowFilter


class NoFilter(WindowFilter):
    """Passes the latest sample through; keeps no samples (streaming Welford deviation)."""

    type_name = "nofilter"
    __slots__ = ()

    def __init__(self, deviation: str = STD_DEVIATION) -> None:
        super().__init__(None, deviation)

    @classmethod
    def from_config(cls, node: ConfigNode) -> NoFilter:
        node.check_keys(("type", "deviation"))
        return cls(params.deviation_type(node))

    def get(self) -> float | None:
        return self._window.last


FILTERS.add(NoFilter.type_name, NoFilter.from_config, example={"type": "nofilter"})
