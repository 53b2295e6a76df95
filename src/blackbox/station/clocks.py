"""Whether a robot's clock can be believed, judged by the station's own clock.

Every sample carries the robot's time. A robot whose clock is minutes off (no NTP at a
remote site, a lost real-time clock battery) would put its failures minutes into the past
or the future of the fleet's timeline, where nobody looks. The station compares each live
characteristic value's time with the time it received it. A delay makes samples look older,
never younger, so the smallest difference over the last :data:`WINDOW` seconds is the
robot's clock offset (plus the shortest delay): ahead of the station by more than
:data:`LIMIT`, or behind by more than that for a whole window, the robot's clock is
implausible. Its events are then placed at the station's receive time (the robot's own time
kept in the event's details), and the skew is a problem on every page until it is gone.

Pure bookkeeping (time passed in); the follower's thread calls it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

LIMIT = 60.0
"""Seconds of difference between a robot's clock and the station's beyond which the robot's
times are not believed (delivery over a healthy link takes well under a second)."""
WINDOW = 10.0
"""Seconds of received samples over which the smallest difference is taken."""


@dataclass(slots=True)
class _Offsets:
    samples: deque[tuple[float, float]] = field(default_factory=deque)
    """(received, received - robot time) over :data:`WINDOW`, oldest first, keeping only
    those that can still be the window's smallest difference (each smaller than every later
    one): the first is the minimum, found without walking the window on every sample (a
    robot sends a dozen samples a second, a fleet of 1,000 some 11,000)."""
    first: float | None = None
    skewed: bool = False


def _words(offset: float) -> str:
    minutes = abs(offset) / 60.0
    size = f"{minutes:.0f} min" if minutes >= 1.5 else f"{abs(offset):.0f} s"
    return f"{size} {'behind' if offset > 0 else 'ahead of'}"


class ClockWatch:
    """The clock offsets of every robot, with problems reported through ``report(source,
    message)`` and withdrawn with ``clear(source)``."""

    def __init__(self, report: Callable[[str, str], None],
                 clear: Callable[[str], None], limit: float = LIMIT,
                 window: float = WINDOW) -> None:
        self._report = report
        self._clear = clear
        self.limit = limit
        self.window = window
        self._robots: dict[str, _Offsets] = {}

    def observe(self, robot: str, robot_time: float, received: float) -> None:
        """A live sample of ``robot`` stamped ``robot_time`` arrived at ``received``."""
        o = self._robots.get(robot)
        if o is None:  # (not setdefault: that made a new _Offsets for every sample)
            o = self._robots[robot] = _Offsets()
        o.first = received if o.first is None else o.first
        difference = received - robot_time
        while o.samples and o.samples[-1][1] >= difference:
            o.samples.pop()  # never the minimum again while this one is in the window
        o.samples.append((received, difference))
        while received - o.samples[0][0] > self.window:
            o.samples.popleft()
        offset = o.samples[0][1]
        whole_window = received - o.first >= self.window
        skewed = offset < -self.limit or (offset > self.limit and whole_window)
        if skewed:
            self._clear(f"clock {robot}")
            self._report(f"clock {robot}", f"{robot}: its clock is {_words(offset)} the "
                                           "station's; its events are placed at the time the "
                                           "station received them")
        elif o.skewed:
            self._clear(f"clock {robot}")
        o.skewed = skewed

    def skewed(self, robot: str) -> bool:
        o = self._robots.get(robot)
        return o is not None and o.skewed

    def time_of(self, robot: str, robot_time: float, received: float) -> float:
        """Where an event of ``robot`` goes on the timeline: its own time, or the station's
        receive time while the robot's clock is implausible."""
        return received if self.skewed(robot) else robot_time
