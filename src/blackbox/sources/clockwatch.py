"""A live source watching its own clocks: the black box paused, starved or its clock stepped.

A live source stamps events with the wall clock and its ``poll`` sleeps until the
pipeline's next evaluation. Two things make that time line lie about the robot:

* the black box itself did not run for a while (``SIGSTOP``, a starved CPU, a suspended
  virtual machine): ``poll`` wakes long after the time it was asked to wake at, and what
  its threads should have seen meanwhile (counted arrivals, probe answers) is missing or
  late, which would look like a stalled topic;
* the wall clock was stepped (NTP, an operator): a forward step looks like a silence as
  long as the step, a backward one like time standing still.

The monotonic clock tells both apart from the robot's behaviour. :class:`ClockWatch`
compares the two clocks at every poll and turns either into a
:class:`~blackbox.events.MeasurementGap` of everything, so observers leave the interval
unjudged instead of raising a time-out or a wrong rate.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from blackbox.events import MeasurementGap

PAUSE_LIMIT = 1.0
"""Seconds ``poll`` may wake late before the black box counts itself as having been paused."""

STEP_LIMIT = 0.5
"""Seconds the wall clock may drift from the monotonic one between two polls before it
counts as stepped."""


class ClockWatch:
    """Compares the wall and monotonic clocks across polls of one live source.

    ``wall`` and ``monotonic`` are the clocks read; tests replace them to step the wall
    clock without touching the machine's (the source boundary is the only place a live
    source reads the time of its events from).
    """

    def __init__(self, wall: Callable[[], float] = time.time,
                 monotonic: Callable[[], float] = time.monotonic,
                 pause_limit: float = PAUSE_LIMIT, step_limit: float = STEP_LIMIT) -> None:
        self.wall = wall
        self.monotonic = monotonic
        self.pause_limit = pause_limit
        self.step_limit = step_limit
        self._wall: float | None = None
        self._mono = 0.0

    def check(self, expected: float | None = None) -> MeasurementGap | None:
        """A gap since the last check: a wall-clock step, or (``expected`` given: the wall
        time this poll meant to wake at) a wake more than ``pause_limit`` late."""
        wall, mono = self.wall(), self.monotonic()
        last_wall, last_mono = self._wall, self._mono
        self._wall, self._mono = wall, mono
        if last_wall is None:
            return None
        step = (wall - last_wall) - (mono - last_mono)
        if abs(step) > self.step_limit:
            way = "forward" if step > 0 else "back"
            return MeasurementGap(wall, last_wall, wall,
                                  f"the black box's wall clock was stepped {way} by "
                                  f"{abs(step):.3g} s")
        if expected is not None and wall - expected > self.pause_limit:
            return MeasurementGap(wall, last_wall, wall,
                                  f"the black box did not run for {wall - expected:.3g} s "
                                  "(paused or starved of CPU)")
        return None
