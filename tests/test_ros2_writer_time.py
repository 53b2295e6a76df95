"""Arrival times of DDS samples come from their writers' clocks, not from when the black
box's DDS thread got round to taking them (``sources/ros2/writer_time.py``)."""

from __future__ import annotations

import itertools
import random

import pytest

from blackbox.sources.ros2.writer_time import EARLIEST, STEP_AFTER, WriterDelay


def test_a_steady_writer_keeps_its_spacing_however_late_the_takes() -> None:
    rng = random.Random(1)
    clock = WriterDelay()
    offset = 0.0005  # the shortest transport time
    arrivals = []
    for i in range(1000):
        sent = 100.0 + i * 0.01
        late = rng.choice([0.0, 0.0, 0.002, 0.03, 0.1])  # the interpreter was busy
        arrivals.append(clock.arrival(7, sent, sent + offset + late))
    periods = [b - a for a, b in itertools.pairwise(arrivals[100:])]
    assert max(periods) == pytest.approx(0.01, abs=1e-3)
    assert min(periods) == pytest.approx(0.01, abs=1e-3)


def test_a_writer_on_another_clock_is_placed_on_this_one() -> None:
    clock = WriterDelay()
    times = [clock.arrival(1, 5000.0 + i * 0.1, 20.0 + i * 0.1 + 0.001 * (i % 3))
             for i in range(50)]
    assert all(abs(t - (20.0 + i * 0.1)) < 0.005 for i, t in enumerate(times))


def test_no_sample_arrives_after_it_was_taken() -> None:
    clock = WriterDelay()
    clock.arrival(1, 10.0, 10.001)
    # a sample whose source timestamp lies after its take on this clock's reckoning
    assert clock.arrival(1, 10.5, 10.2) <= 10.2


def test_a_stepped_clock_is_followed_after_a_while_and_not_before() -> None:
    clock = WriterDelay()
    for i in range(100):
        clock.arrival(3, i * 0.1, i * 0.1 + 0.001)
    # the writer's clock steps back by 3 s: every delay now reads 3 s longer
    t = 10.0
    first = clock.arrival(3, t - 3.0, t + 0.001)
    assert first == pytest.approx(t + 0.001 - EARLIEST)  # not yet believed
    while t < 10.0 + STEP_AFTER + 0.5:
        t += 0.1
        last = clock.arrival(3, t - 3.0, t + 0.001)
    assert last == pytest.approx(t + 0.001, abs=0.01)


def test_writers_are_followed_apart() -> None:
    clock = WriterDelay()
    clock.arrival(1, 0.0, 0.001)
    clock.arrival(2, 100.0, 0.002)
    assert clock.arrival(1, 0.1, 0.2) == pytest.approx(0.101, abs=1e-3)
    assert clock.arrival(2, 100.1, 0.2) == pytest.approx(0.102, abs=1e-3)
