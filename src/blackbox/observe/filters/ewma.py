"""Exponentially weighted moving average: ``x = x_old * (1 - d) + sample * d``.

The first sample is taken as is. Without ``window_size`` the average runs over all samples
(O(1) per sample, the deviation over all samples so far). With ``window_size`` the average
is recomputed over the window's samples in arrival order, starting from the oldest, which
is what the TU Graz tool does: old samples leave the average completely instead of fading.
"""

from __future__ import annotations

from math import isfinite

from blackbox.config.node import ConfigNode
from blackbox.observe.base import FILTERS
from blackbox.observe.filters import params
from blackbox.observe.filters.window import STD_DEVIATION, WindowFilter


class EwmaFilter(WindowFilter):
    """O(1) per sample; with a window, ``get`` costs O(window) once per new sample."""

    type_name = "ewma"
    __slots__ = ("_fresh", "_value", "decay_rate")

    def __init__(self, decay_rate: float, window_size: int | None = None,
                 deviation: str = STD_DEVIATION) -> None:
        if not 0.0 < decay_rate <= 1.0:
            raise ValueError(f"decay_rate must be in (0, 1], got {decay_rate}")
        super().__init__(window_size, deviation)
        self.decay_rate = decay_rate
        self._value: float | None = None
        self._fresh = True

    @classmethod
    def from_config(cls, node: ConfigNode) -> EwmaFilter:
        node.check_keys(("type", "decay_rate", "window_size", "deviation"))
        return cls(params.decay_rate(node), params.optional_window_size(node),
                   params.deviation_type(node))

    def update(self, x: float) -> None:
        if not isfinite(x):
            self.rejected += 1
            return
        self._window.push(x)
        if self._window.size is not None:
            self._fresh = False
        elif self._value is None:
            self._value = x
        else:
            # Same as value * (1 - d) + x * d, but exact when x equals the value.
            self._value += self.decay_rate * (x - self._value)

    def get(self) -> float | None:
        if self._fresh:
            return self._value
        samples = iter(self._window.samples)
        d = self.decay_rate
        value = next(samples, None)
        if value is not None:
            for x in samples:
                value += d * (x - value)
        self._value = value
        self._fresh = True
        return value

    def reset(self) -> None:
        super().reset()
        self._value = None
        self._fresh = True

    def describe(self) -> str:
        return f"ewma (decay_rate {self.decay_rate:g}, {self._describe_window()})"


FILTERS.add(EwmaFilter.type_name, EwmaFilter.from_config,
            example={"type": "ewma", "decay_rate": 0.3, "window_size": 5})
