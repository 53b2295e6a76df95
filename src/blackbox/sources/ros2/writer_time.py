"""When a DDS sample arrived, from its writer's source timestamp rather than its take.

The DDS thread takes samples when it gets the interpreter: behind the pipeline, a busy
take or a loaded core, that is milliseconds to a hundred after they arrived (the real
diffdrive robot's messages reached the black box 0.5 ms after their header stamp at the
median and up to 100-200 ms at the tail under load). Stamped at the take, a steady 100 Hz
IMU reads as bursts and pauses, and a learned relation between two signals sees a
sample's value displaced in time by that lateness (an error of the signal's slope times
it, several noise deviations on a turning robot).

Every DDS sample carries its writer's ``source_timestamp``. The writer's clock may be
another host's, so it is not used as it is: per writer, :class:`WriterDelay` follows the
least delay from source timestamp to take (the clock offset plus the shortest transport
time) and stamps each sample at ``source timestamp + least delay``, never after its take.
The least delay may grow slowly (``RISE`` per second: clocks drift); a step of either
clock shows as every delay well above it for ``STEP_AFTER`` seconds, and it starts again
from the least delay of that stretch. No sample is placed after its take, nor more than
``EARLIEST`` before it.
"""

from __future__ import annotations

from dataclasses import dataclass

RISE = 0.002
"""Seconds per second by which the least delay of a writer may grow (clock drift)."""
STEP = 0.25
"""A delay this much above the least one is late, not a sample of the least delay."""
STEP_AFTER = 2.0
"""Seconds of nothing but late samples after which a writer's clock counts as stepped."""
EARLIEST = 1.0
"""A sample is placed at most this many seconds before its take (longer is a stepped clock
not yet followed, or the black box starved: its own measurement gap)."""


@dataclass(slots=True)
class _Writer:
    least: float
    taken: float
    late_since: float | None = None
    least_late: float = 0.0


class WriterDelay:
    """Arrival times of DDS samples from their writers' source timestamps (module doc)."""

    def __init__(self) -> None:
        self._writers: dict[int, _Writer] = {}

    def arrival(self, writer: int, sent: float, taken: float) -> float:
        """The arrival time of a sample ``writer`` sent at ``sent`` (its clock, seconds)
        and this source took at ``taken`` (wall clock)."""
        delay = taken - sent
        w = self._writers.get(writer)
        if w is None:
            self._writers[writer] = _Writer(delay, taken)
            return taken
        least = w.least + RISE * max(0.0, taken - w.taken)
        w.taken = taken
        if delay <= least + STEP:
            w.late_since = None
            w.least = min(least, delay)
        elif w.late_since is None:
            w.late_since, w.least_late, w.least = taken, delay, least
        else:
            w.least_late = min(w.least_late, delay)
            w.least = least
            if taken - w.late_since >= STEP_AFTER:
                w.least, w.late_since = w.least_late, None
        return min(taken, max(taken - EARLIEST, sent + w.least))
