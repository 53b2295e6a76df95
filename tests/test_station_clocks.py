"""The station's clock watch judges a robot's clock by the smallest receive-minus-robot
difference over its window; it keeps only the candidates for that minimum, and must judge
exactly as taking the minimum over every sample of the window would."""

from __future__ import annotations

import random

from blackbox.station.clocks import ClockWatch


def test_the_offset_is_the_smallest_difference_of_the_window_whatever_the_sequence() -> None:
    rng = random.Random(7)
    reported: list[str] = []
    watch = ClockWatch(lambda source, message: reported.append(message), lambda source: None,
                       limit=60.0, window=10.0)
    seen: list[tuple[float, float]] = []
    received = 1_000.0
    for _ in range(5_000):
        received += rng.choice([0.0, 0.01, 0.3, 2.0])
        offset = rng.choice([-120.0, -1.0, 0.0, 0.2, 5.0, 90.0]) + rng.random()
        watch.observe("r", received - offset, received)
        seen.append((received, offset))
        window = [d for at, d in seen if received - at <= 10.0]
        smallest = min(window)
        skewed = smallest < -60.0 or (smallest > 60.0 and received - seen[0][0] >= 10.0)
        assert watch.skewed("r") is skewed, (received, smallest)
