"""Time-stamped samples of single numeric signals, kept while learning for relations.

The envelope rules (``blackbox.learn.model``) only need each field's values in order;
relations between topics need *when* each value arrived, to line different rates and
delays up. A signal is a scalar field or one element of a short numeric array
(``velocity[1]``); arrays longer than ``MAX_ELEMENTS`` (a laser scan) are left to their
summaries. Memory is bounded: past ``MAX_SAMPLES`` a signal keeps every second sample.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field

import numpy as np

MAX_ELEMENTS = 16
MAX_SAMPLES = 400_000


@dataclass
class TimedSeries:
    """Arrival times and values of one signal, in arrival order."""

    times: array[float] = field(default_factory=lambda: array("d"))
    values: array[float] = field(default_factory=lambda: array("d"))
    non_finite: int = 0
    stride: int = 1
    skip: int = 0

    def add(self, t: float, x: float) -> None:
        if x != x or x in (float("inf"), float("-inf")):
            self.non_finite += 1
            return
        if self.skip:
            self.skip -= 1
            return
        self.times.append(t)
        self.values.append(x)
        self.skip = self.stride - 1
        if len(self.values) >= MAX_SAMPLES:
            self.times = self.times[::2]
            self.values = self.values[::2]
            self.stride *= 2

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return (np.frombuffer(self.times, dtype=np.float64).copy(),
                np.frombuffer(self.values, dtype=np.float64).copy())

    def __len__(self) -> int:
        return len(self.values)
