"""Robust statistics of a healthy run, and the rule that picks a filter window and bounds.

The rule (docs/learn.md, "Windows and bounds") repeats the thesis's Fig. 6.10 experiment
on the learning run itself: for each candidate window of a mean filter it replays the
filter over the recorded samples, takes the robust band the filtered value stayed in
(0.1 % and 99.9 % quantiles), widens it by a margin, and keeps the *smallest* window whose
bounds would still catch a level shift of ``SHIFT_SIGMAS`` standard deviations of the raw
noise. Smaller windows react sooner (Fig. 6.11); larger ones would have raised false alarms
on the healthy run itself less often (Fig. 6.10). When no window reaches that sensitivity
the window with the tightest bounds is taken and the comment says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

WINDOWS = (1, 2, 5, 10, 20, 50, 100)
"""Candidate mean-filter windows, smallest first."""
BAND_QUANTILES = (0.001, 0.999)
"""The robust band of a filtered value: a single hiccup in the learning run does not set it."""
MARGIN = 1.0
"""The band is widened by this multiple of its half-width on each side (it doubles)."""
SHIFT_SIGMAS = 2.0
"""A shift of the level by this many raw-noise standard deviations must leave the bounds."""
MIN_WINDOWS_PER_CANDIDATE = 10
"""A window is only tried when the run holds this many non-overlapping windows of it."""
MIN_SAMPLES = 20
"""Fewer samples than this: too little data to learn bounds for a quantity."""
RESOLUTION = 1e-9
"""Relative noise below this is floating-point rounding, not noise."""


def quantile(x: np.ndarray, q: float) -> float:
    return float(np.quantile(x, q)) if x.size else math.nan


def robust_sigma(x: np.ndarray) -> float:
    """1.4826 x median absolute deviation (the standard deviation for Gaussian noise); the
    plain standard deviation when more than half the samples are equal."""
    if x.size < 2:
        return 0.0
    mad = float(np.median(np.abs(x - np.median(x))))
    if mad > 0:
        return 1.4826 * mad
    return float(np.std(x, ddof=1))


def rolling_mean(x: np.ndarray, window: int) -> np.ndarray:
    """Mean of every full window of ``window`` consecutive samples."""
    if window <= 1:
        return x
    c = np.cumsum(np.concatenate(([0.0], x)))
    out: np.ndarray = (c[window:] - c[:-window]) / window
    return out


@dataclass(frozen=True, slots=True)
class Bounds:
    """A learned filter window and the interval its filtered value must stay in."""

    window: int
    lower: float
    upper: float
    band: tuple[float, float]
    sigma: float
    center: float
    sensitive: bool
    """Whether a shift of SHIFT_SIGMAS raw standard deviations leaves the bounds."""

    @property
    def shift_caught(self) -> float:
        """The smallest level shift, in raw standard deviations, that leaves the bounds."""
        if self.sigma <= 0:
            return 0.0
        return min(self.upper - self.center, self.center - self.lower) / self.sigma


def learn_bounds(samples: Sequence[float] | np.ndarray, *, floor: float = 0.0,
                 max_window: int = WINDOWS[-1]) -> Bounds | None:
    """The window and bounds for ``samples`` by the module's rule; ``None`` with fewer than
    ``MIN_SAMPLES`` samples. ``floor`` is the smallest margin on each side (absolute)."""
    x = np.asarray(samples, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size < MIN_SAMPLES:
        return None
    sigma = robust_sigma(x)
    center = float(np.median(x))
    if sigma <= RESOLUTION * max(1.0, abs(center)):
        sigma = 0.0  # rounding noise of a constant (an age of 0 computed from floats)
    best: Bounds | None = None
    for window in WINDOWS:
        if window > max_window or (window > 1 and x.size < window * MIN_WINDOWS_PER_CANDIDATE):
            break
        filtered = rolling_mean(x, window)
        lo, hi = quantile(filtered, BAND_QUANTILES[0]), quantile(filtered, BAND_QUANTILES[1])
        margin = max(MARGIN * (hi - lo) / 2, floor)
        lower, upper = lo - margin, hi + margin
        reach = max(upper - center, center - lower)
        sensitive = sigma > 0 and reach <= SHIFT_SIGMAS * sigma
        candidate = Bounds(window, lower, upper, (lo, hi), sigma, center, sensitive)
        if sensitive:
            return candidate
        if best is None or (upper - lower) < (best.upper - best.lower):
            best = candidate
        if sigma == 0:
            break
    return best


def lengthened(samples: Sequence[float] | np.ndarray, bounds: Bounds, window: int, *,
               floor: float = 0.0) -> Bounds:
    """``bounds`` over the longer ``window`` when its band is no wider (a band set by its
    ``floor``, as every learned rate band is): the same sensitivity to a lasting shift, and
    a short excursion is averaged over more samples. ``bounds`` itself otherwise, or when
    the run holds fewer than ``MIN_WINDOWS_PER_CANDIDATE`` windows of that length."""
    x = np.asarray(samples, dtype=np.float64)
    x = x[np.isfinite(x)]
    if window <= bounds.window or x.size < window * MIN_WINDOWS_PER_CANDIDATE:
        return bounds
    filtered = rolling_mean(x, window)
    lo, hi = quantile(filtered, BAND_QUANTILES[0]), quantile(filtered, BAND_QUANTILES[1])
    margin = max(MARGIN * (hi - lo) / 2, floor)
    lower, upper = lo - margin, hi + margin
    if upper - lower > (bounds.upper - bounds.lower) * (1 + 1e-9):
        return bounds
    reach = max(upper - bounds.center, bounds.center - lower)
    return Bounds(window, lower, upper, (lo, hi), bounds.sigma, bounds.center,
                  bounds.sigma > 0 and reach <= SHIFT_SIGMAS * bounds.sigma)


def round_down(x: float, digits: int = 4) -> float:
    """``x`` to ``digits`` significant digits, never above ``x``."""
    return _round(x, digits, math.floor)


def round_up(x: float, digits: int = 4) -> float:
    """``x`` to ``digits`` significant digits, never below ``x``."""
    return _round(x, digits, math.ceil)


def _round(x: float, digits: int, how: object) -> float:
    if x == 0 or not math.isfinite(x):
        return x
    scale = 10 ** (digits - 1 - math.floor(math.log10(abs(x))))
    value = how(x * scale) / scale  # type: ignore[operator]
    return float(f"{value:.{digits + 2}g}")
