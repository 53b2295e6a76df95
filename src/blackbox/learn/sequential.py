"""Calibrating a CUSUM's alarm threshold from healthy data for a stated false-alarm rate.

A two-sided CUSUM with drift ``k`` on standardised, roughly independent block statistics
(block means of a residual, block log-variances) raises a false alarm on average every
ARL0 blocks. Siegmund's approximation gives ARL0 for one side as
``(exp(2 k b) - 2 k b - 1) / (2 k^2)`` with ``b = h + 1.166``; two sides halve it. The
threshold ``h`` is the smallest with ``ARL0 >= blocks per hour / rate``.

Real residuals are not Gaussian (heavier tails, some correlation left between blocks), so
the threshold is then checked against the healthy data itself: a stationary block
bootstrap of the healthy standardised statistics, ``BOOTSTRAP_HOURS`` simulated hours of
them, must not raise a single alarm, else ``h`` is raised by 10 % until it does not (at
most ``MAX_RAISES`` times). The healthy run is short (two minutes), so this guards against
tails the Gaussian formula misses; it cannot prove a rate of one alarm in a hundred hours,
and the documentation says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

K = 0.5
"""Drift: the CUSUM is tuned for a shift of one block noise (2 k)."""
BOOTSTRAP_HOURS = 20.0
MAX_RAISES = 25
MARGIN = 1.3
"""The threshold is at least this many times the Gaussian one."""
BOOTSTRAP_BLOCK = 8
"""Statistics resampled in runs of this many, keeping short-range correlation."""


def siegmund_arl(h: float, k: float = K) -> float:
    """Average run length of a two-sided CUSUM on N(0, 1) statistics, in blocks."""
    b = h + 1.166
    if k == 0:
        return b * b
    one = (math.exp(min(700.0, 2 * k * b)) - 2 * k * b - 1) / (2 * k * k)
    return one / 2


def threshold_for(arl: float, k: float = K) -> float:
    """The smallest ``h`` whose ARL0 reaches ``arl`` blocks (bisection)."""
    lo, hi = 0.0, 1.0
    while siegmund_arl(hi, k) < arl:
        hi *= 2
    for _ in range(60):
        mid = (lo + hi) / 2
        if siegmund_arl(mid, k) < arl:
            lo = mid
        else:
            hi = mid
    return hi


def alarms(z: np.ndarray, h: float, k: float = K, two_sided: bool = True) -> int:
    """How many times a CUSUM over ``z`` reaches ``h`` (restarting after each alarm)."""
    up = down = 0.0
    count = 0
    for x in z.tolist():
        up = max(0.0, up + x - k)
        if two_sided:
            down = max(0.0, down - x - k)
        if up >= h or down >= h:
            count += 1
            up = down = 0.0
    return count


def _bootstrap_alarms(z: np.ndarray, blocks: int, h: float, k: float, two_sided: bool,
                      rng: np.random.Generator, replicates: int = 16) -> int:
    """Alarms over ``replicates`` bootstrap series of ``blocks`` statistics each, run side by
    side (one vectorised step per block)."""
    n = z.size
    runs = -(-blocks // BOOTSTRAP_BLOCK)
    starts = rng.integers(0, max(1, n - BOOTSTRAP_BLOCK), size=(replicates, runs))
    idx = (starts[:, :, None] + np.arange(BOOTSTRAP_BLOCK)[None, None, :]).reshape(
        replicates, -1)[:, :blocks]
    series = z[np.minimum(idx, n - 1)]
    up = np.zeros(replicates)
    down = np.zeros(replicates)
    total = 0
    for j in range(series.shape[1]):
        x = series[:, j]
        up = np.maximum(0.0, up + x - k)
        if two_sided:
            down = np.maximum(0.0, down - x - k)
        hit = (up >= h) | (down >= h)
        if hit.any():
            total += int(hit.sum())
            up[hit] = 0.0
            down[hit] = 0.0
    return total


@dataclass(frozen=True, slots=True)
class Calibration:
    h: float
    k: float
    h_gauss: float
    """The threshold the Gaussian formula gave, before the bootstrap raised it."""
    arl_hours: float
    """Mean time between false alarms the Gaussian formula promises at ``h_gauss``."""
    healthy_max: float
    """Largest CUSUM statistic on the healthy statistics themselves."""

    def describe(self) -> str:
        raised = (f", raised to {self.h:.3g} by the bootstrap" if self.h > self.h_gauss + 1e-9
                  else "")
        return (f"CUSUM k {self.k:g}, h {self.h_gauss:.3g} for one false alarm in "
                f"{self.arl_hours:,.0f} h{raised}; healthy max {self.healthy_max:.2g}")


def calibrate(z: np.ndarray, blocks_per_hour: float, rate_per_hour: float, *,
              k: float = K, two_sided: bool = True, seed: int = 0) -> Calibration:
    """The threshold for ``rate_per_hour`` false alarms on standardised healthy ``z``."""
    arl = blocks_per_hour / rate_per_hour
    h0 = threshold_for(arl * (1 if two_sided else 0.5), k)
    healthy_max = _max_statistic(z, k, two_sided)
    # two minutes of residuals understate their tails: a margin over the Gaussian value
    # (measured: one relation at the Gaussian h raised 9 alarms in two healthy hours)
    h = max(MARGIN * h0, 1.25 * healthy_max)
    rng = np.random.default_rng(seed)
    blocks = int(BOOTSTRAP_HOURS * blocks_per_hour / 16) + 1
    for _ in range(MAX_RAISES):
        if z.size < 2 * BOOTSTRAP_BLOCK or _bootstrap_alarms(z, blocks, h, k, two_sided,
                                                             rng) == 0:
            break
        h *= 1.1
    return Calibration(h, k, h0, arl / blocks_per_hour, healthy_max)


def _max_statistic(z: np.ndarray, k: float, two_sided: bool) -> float:
    up = down = best = 0.0
    for x in z.tolist():
        up = max(0.0, up + x - k)
        if two_sided:
            down = max(0.0, down - x - k)
        best = max(best, up, down)
    return best
