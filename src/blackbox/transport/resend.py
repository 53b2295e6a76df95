"""Resending a command that got no answer, and telling a resend from a new command.

Discovery is not symmetric: a station that has just started can see the robot's command
reader before the robot has seen the station's answer reader. Command topics are volatile,
so the robot's first answer (or the command itself) can go to nobody and the station would
wait out its whole time-out. The station therefore writes the same command again (same
identifier) while nothing has come back, and the robot answers a repeat only when it is not
merely crossing the answer just sent. A signed command is signed anew for each write (the
robot takes a nonce once), and the robot checks the signature before it looks for repeats,
so a captured command written again is still refused as a replay.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

RESEND_FIRST = 1.0
RESEND_MAX = 4.0
REPEAT_AFTER = 0.5
"""A command seen again within this many seconds of its answer is a resend crossing that
answer and is not answered again; later, the answer was lost and it is."""
REMEMBERED = 64

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


@dataclass
class Resend:
    """When a command that got no answer at all is written again: waits double from
    :data:`RESEND_FIRST` to at most :data:`RESEND_MAX` seconds."""

    sent: float
    wait: float = RESEND_FIRST

    def due(self, now: float) -> bool:
        if now - self.sent < self.wait:
            return False
        self.sent, self.wait = now, min(self.wait * 2, RESEND_MAX)
        return True


@dataclass
class RecentAnswers(Generic[K, V]):
    """The robot's memory of the last :data:`REMEMBERED` commands it answered, and when."""

    entries: OrderedDict[K, tuple[float, V]] = field(default_factory=OrderedDict)

    def crossing(self, key: K, now: float) -> bool:
        """Whether a command with ``key`` is a resend crossing the answer just sent."""
        seen = self.entries.get(key)
        return seen is not None and now - seen[0] < REPEAT_AFTER

    def get(self, key: K) -> V | None:
        seen = self.entries.get(key)
        return None if seen is None else seen[1]

    def answered(self, key: K, now: float, answer: V) -> None:
        self.entries[key] = (now, answer)
        self.entries.move_to_end(key)
        while len(self.entries) > REMEMBERED:
            self.entries.popitem(last=False)
