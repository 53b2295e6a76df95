"""Sample windows with constant-time statistics, shared by every filter.

A :class:`Window` holds the last ``size`` samples (or, with ``size=None``, summarises all
samples so far without keeping them) and maintains what the deviation checks need: the
mean and the sum of squared deviations (Welford, with an O(1) replace step when the window
slides) and, on request, the minimum and maximum (monotonic deques).

Running sums drift: each slide adds a rounding error. Every ``recompute_every`` slides the
moments are recomputed exactly from the window (amortised O(1)). A window whose samples are
all equal is detected by a run counter and reports the sample itself as mean and exactly
0.0 as deviation, so constant input never shows a spurious ``1e-17`` spread.
"""

from __future__ import annotations

from collections import deque
from math import fsum, isfinite, sqrt
from typing import ClassVar, Final, Self

from sortedcontainers import SortedList

from blackbox.observe.base import Summary

STD_DEVIATION: Final = "std_deviation"
MIN_MAX: Final = "min_max"
DEVIATION_TYPES: Final = (STD_DEVIATION, MIN_MAX)


class Window:
    """The last ``size`` samples and their mean, variance and (optionally) extremes."""

    __slots__ = ("_hi", "_last", "_lo", "_m2", "_mean", "_n", "_run", "_since_exact",
                 "extremes", "recompute_every", "samples", "size")

    def __init__(self, size: int | None, *, extremes: bool = False) -> None:
        if size is not None and size < 1:
            raise ValueError(f"window size must be >= 1, got {size}")
        self.size = size
        self.extremes = extremes
        self.recompute_every = max(4 * size, 1024) if size is not None else 0
        self.samples: deque[float] = deque(maxlen=size) if size is not None else deque(maxlen=0)
        self._hi: deque[float] = deque()
        self._lo: deque[float] = deque()
        self.clear()

    def clear(self) -> None:
        self.samples.clear()
        self._hi.clear()
        self._lo.clear()
        self._n = 0
        self._mean = 0.0
        self._m2 = 0.0
        self._run = 0
        self._last = 0.0
        self._since_exact = 0

    def __len__(self) -> int:
        return self._n

    def copy(self) -> Window:
        clone = object.__new__(Window)
        for name in Window.__slots__:
            value = getattr(self, name)
            setattr(clone, name, value.copy() if isinstance(value, deque) else value)
        return clone

    def push(self, x: float) -> float | None:
        """Add ``x``; returns the sample that fell out of the window, if any."""
        if x == self._last:
            self._run += 1
        else:
            self._run = 1
            self._last = x
        n = self._n
        if n == self.size:
            samples = self.samples
            y = samples[0]
            samples.append(x)
            if self.extremes:
                # Monotonic deques. Strict popping keeps equal values, so the evicted
                # sample, if still in a deque, is at its front.
                self._grow_extremes(x)
                hi, lo = self._hi, self._lo
                if hi[0] == y:
                    hi.popleft()
                if lo[0] == y:
                    lo.popleft()
            d = x - y
            if d:
                mean = self._mean
                new_mean = mean + d / n
                self._m2 += d * (x - new_mean + y - mean)
                self._mean = new_mean
            self._since_exact += 1
            if self._since_exact >= self.recompute_every:
                self._recompute()
            return y
        if self.size is not None:
            self.samples.append(x)
        if self.extremes:
            self._grow_extremes(x)
        n += 1
        self._n = n
        if n == 1:
            self._mean = x
            self._m2 = 0.0
        else:
            d = x - self._mean
            self._mean += d / n
            self._m2 += d * (x - self._mean)
        return None

    def _grow_extremes(self, x: float) -> None:
        hi, lo = self._hi, self._lo
        if self.size is None:
            if not hi:
                hi.append(x)
                lo.append(x)
            elif x > hi[0]:
                hi[0] = x
            elif x < lo[0]:
                lo[0] = x
            return
        while hi and hi[-1] < x:
            hi.pop()
        hi.append(x)
        while lo and lo[-1] > x:
            lo.pop()
        lo.append(x)

    def _recompute(self) -> None:
        samples = self.samples
        first = samples[0]
        mean = first + fsum([v - first for v in samples]) / len(samples)
        self._mean = mean
        self._m2 = fsum([(v - mean) * (v - mean) for v in samples])
        self._since_exact = 0

    @property
    def constant(self) -> bool:
        """All samples in the window are equal (and there is at least one)."""
        return self._n > 0 and self._run >= self._n

    @property
    def last(self) -> float | None:
        return self._last if self._n else None

    def mean(self) -> float | None:
        if not self._n:
            return None
        return self._last if self._run >= self._n else self._mean

    def std(self) -> float | None:
        """Sample standard deviation (n - 1); ``None`` below two samples."""
        n = self._n
        if n < 2:
            return None
        if self._run >= n:
            return 0.0
        m2 = self._m2
        return sqrt(m2 / (n - 1)) if m2 > 0.0 else 0.0

    def spread(self) -> float | None:
        """``max - min``; needs ``extremes=True``. ``None`` before the first sample."""
        if not self.extremes:
            raise RuntimeError("window built without extremes")
        if not self._n:
            return None
        return self._hi[0] - self._lo[0]

    def deviation(self, kind: str) -> float | None:
        return self.spread() if kind == MIN_MAX else self.std()


class WindowFilter:
    """Common part of the filters: a :class:`Window`, the deviation and the summary.

    Non-finite samples (NaN, infinities) from a misbehaving robot are not filtered: they
    would poison every later statistic. They are dropped and counted in ``rejected``.
    ``count()`` is the number of samples the deviation is computed over (the window, or all
    samples so far without a window).
    """

    type_name: ClassVar[str] = ""
    __slots__ = ("_window", "deviation_type", "rejected")

    def __init__(self, window_size: int | None, deviation: str = STD_DEVIATION) -> None:
        if deviation not in DEVIATION_TYPES:
            raise ValueError(f"unknown deviation type {deviation!r}")
        self.deviation_type = deviation
        self._window = Window(window_size, extremes=deviation == MIN_MAX)
        self.rejected = 0

    @property
    def window_size(self) -> int | None:
        return self._window.size

    def update(self, x: float) -> None:
        if isfinite(x):
            self._window.push(x)
        else:
            self.rejected += 1

    def get(self) -> float | None:
        raise NotImplementedError

    def deviation(self) -> float | None:
        return self._window.deviation(self.deviation_type)

    def count(self) -> int:
        return len(self._window)

    def summary(self) -> Summary | None:
        value = self.get()
        if value is None:
            return None
        return Summary(value, self._window.deviation(self.deviation_type), len(self._window))

    def reset(self) -> None:
        self._window.clear()
        self.rejected = 0

    def copy(self) -> Self:
        """An independent copy (for probing "what if this sample came next")."""
        clone = object.__new__(type(self))
        for cls in type(self).__mro__:
            for name in getattr(cls, "__slots__", ()):
                value = getattr(self, name)
                setattr(clone, name, value.copy() if hasattr(value, "copy") else value)
        return clone

    def __copy__(self) -> Self:
        return self.copy()

    def __deepcopy__(self, memo: dict[int, object]) -> Self:
        return self.copy()

    def _describe_window(self) -> str:
        size = self._window.size
        span = f"window {size}" if size is not None else "all samples"
        return f"{span}, deviation {self.deviation_type}"

    def describe(self) -> str:
        return f"{self.type_name} ({self._describe_window()})"

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.describe()}>"


class SortedWindowFilter(WindowFilter):
    """A window mirrored in a sorted list, for filters that take order statistics.

    A sample costs O(log n) (one insertion, one removal when the window slides), never a
    sort.
    """

    __slots__ = ("_sorted",)

    def __init__(self, window_size: int, deviation: str = STD_DEVIATION) -> None:
        super().__init__(window_size, deviation)
        self._sorted: SortedList = SortedList()

    def update(self, x: float) -> None:
        if not isfinite(x):
            self.rejected += 1
            return
        evicted = self._window.push(x)
        if evicted is not None:
            self._sorted.remove(evicted)
        self._sorted.add(x)

    def reset(self) -> None:
        super().reset()
        self._sorted.clear()
