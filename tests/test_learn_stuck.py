"""How many equal samples in a row mean a frozen sensor (issue 22 item 5: stuck found
within 2 s at the median). Continuous noise never repeats a value, so a slow signal that
never repeated while learning is stuck at three equal samples; a quantised one, whose
values fall on a grid, or a fast one keeps five."""

from __future__ import annotations

import itertools

import numpy as np

from blackbox.learn.relations import Signal, stuck_repeats
from blackbox.observe.signals import SignalRef


def signal(values: np.ndarray, period: float) -> Signal:
    times = np.arange(values.size) * period
    return Signal(SignalRef("/t", "x"), "x", times, values, period, 0.1, False, None, False)


def longest_run(values: np.ndarray) -> int:
    best = run = 1
    for a, b in itertools.pairwise(values.tolist()):
        run = run + 1 if a == b else 1
        best = max(best, run)
    return best


RNG = np.random.default_rng(3)


def test_a_slow_continuous_signal_is_stuck_at_three_equal_samples():
    temperature = 40.0 + np.cumsum(RNG.normal(0.0, 0.05, 120))  # 1 Hz for two minutes
    assert longest_run(temperature) == 1
    assert stuck_repeats(signal(temperature, 1.0), 1) == 3


def test_a_slow_signal_on_a_grid_keeps_five_even_if_it_never_repeated():
    steps = RNG.choice([-3, -2, -1, 1, 2, 3], 120)  # never zero: no repeat while learning
    percentage = 80.0 + 0.01 * np.cumsum(steps)
    assert longest_run(percentage) == 1
    assert stuck_repeats(signal(percentage, 1.0), 1) == 5


def test_a_fast_signal_keeps_five():
    yaw_rate = RNG.normal(0.0, 0.02, 12_000)  # 100 Hz: five samples are 50 ms
    assert stuck_repeats(signal(yaw_rate, 0.01), 1) == 5


def test_a_signal_that_repeated_while_healthy_needs_twice_its_longest_run():
    slow = np.repeat(RNG.normal(0.0, 1.0, 60), 2)  # every value twice
    assert stuck_repeats(signal(slow, 1.0), 2) == 5
    assert stuck_repeats(signal(slow, 1.0), 3) == 7
    assert stuck_repeats(signal(slow, 1.0), 4) is None
