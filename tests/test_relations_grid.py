"""The grid a relation compares signals on (issue 22): what a signal's value at a grid
point means, the same while learning and while observing, and not shifted in time by where
the samples happen to fall."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blackbox.learn.relations import increasing, window_means
from blackbox.observe.signals import GridCell

STEP = 0.05


def observed(times: np.ndarray, values: np.ndarray, taus: np.ndarray, fresh: float,
             delay: float) -> np.ndarray:
    """What a relation observer's cell gives at each ``tau``, fed sample by sample and asked
    at ``tau + delay`` (once every sample before that moment has arrived)."""
    cell = GridCell(fresh, STEP, delay)
    out = []
    k = 0
    for tau in taus.tolist():
        g = tau + delay
        while k < times.size and times[k] < g:
            cell.add(float(times[k]), float(values[k]))
            k += 1
        out.append(cell.close(g))
    return np.array(out)


def test_learning_and_observing_put_a_signal_on_the_grid_alike():
    rng = np.random.default_rng(1)
    for period in (0.005, 0.02, 0.05, 0.1, 1.0):
        times = np.cumsum(period + rng.normal(0, period / 20, size=int(60 / period)))
        values = np.sin(times) + rng.normal(0, 0.01, size=times.size)
        fresh = 3 * period
        delay = math.ceil((STEP / 2 + 2 * period) / STEP) * STEP
        taus = np.arange(math.ceil(times[0] / STEP) + 40, int(times[-1] / STEP) - 40) * STEP
        learned = window_means(times, values, taus, STEP, fresh)
        online = observed(times, values, taus, fresh, delay)
        assert np.isfinite(learned).all(), period
        np.testing.assert_allclose(online, learned, atol=1e-9, err_msg=f"period {period}")


def test_a_signal_is_not_shifted_by_the_phase_of_its_samples():
    """Two sensors of one ramp sampled at 20 Hz, half a period apart, give the same grid
    values: a cell mean or a held value would lag one of them by up to a period."""
    taus = np.arange(40, 160) * STEP
    grids = []
    for phase in (0.0, 0.025, 0.049):
        times = np.arange(0, 10, 0.05) + phase
        grids.append(window_means(times, 2.0 * times, taus, STEP, 0.15))
    for g in grids[1:]:
        np.testing.assert_allclose(g, grids[0], atol=1e-9)
    np.testing.assert_allclose(grids[0], 2.0 * taus, atol=1e-9)


def test_a_gap_longer_than_fresh_is_stale_not_interpolated():
    times = np.concatenate([np.arange(0, 5, 0.05), np.arange(7, 10, 0.05)])
    taus = np.array([3.0, 6.0, 8.0])
    got = window_means(times, np.ones(times.size), taus, STEP, 0.15)
    assert got[0] == pytest.approx(1.0) and math.isnan(got[1]) and got[2] == pytest.approx(1.0)
    online = observed(times, np.ones(times.size), taus, 0.15, 0.15)
    assert online[0] == pytest.approx(1.0) and math.isnan(online[1])
    assert online[2] == pytest.approx(1.0)


def test_samples_out_of_order_are_dropped_alike():
    times = np.array([0.0, 0.05, 0.04, 0.1, 0.15, 0.15, 0.2])
    t, x = increasing(times, np.arange(times.size, dtype=float))
    assert t.tolist() == [0.0, 0.05, 0.1, 0.15, 0.2]
    assert x.tolist() == [0.0, 1.0, 3.0, 4.0, 6.0]
    cell = GridCell(1.0, STEP, 0.1)
    for a, b in zip(times.tolist(), range(times.size), strict=True):
        cell.add(a, float(b))
    assert [s[0] for s in cell.samples] == t.tolist()
