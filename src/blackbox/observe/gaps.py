"""What an observer remembers of measurement gaps: which are open, when the last one ended.

A :class:`~blackbox.events.MeasurementGap` says the black box could not measure a topic or
node as it normally does for a while. Each observer type has its rule for that interval
(docs/observations.md, "Measurement gaps"); this module holds the bookkeeping they share,
so the rules stay one line each: data stamped inside a gap is not used, an evaluation while
a gap is open says ``NOT_AVAILABLE`` ("not measured since ...") instead of a verdict, and
after the gap the observer starts measuring afresh from its end.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime

from blackbox.events import MeasurementGap
from blackbox.model import Code, Observation, Resource

UNMEASURED = "unmeasured_since"
"""The value key that marks an observation left unjudged for a measurement gap (its value is
the gap's start): a ``NOT_AVAILABLE`` that is the black box's own blind spot, not the
robot's, so campaigns never count it as an alarm (:func:`unmeasured`)."""

_EPOCH_LIKE = 1e8
"""Times above this are seconds since the epoch (a live source); below, a simulated clock."""


def unmeasured(observation: Observation) -> bool:
    """Whether ``observation`` is no verdict because of a measurement gap."""
    return UNMEASURED in observation.values


def moment(t: float) -> str:
    """A time as an operator reads it: UTC clock time for live sources, seconds otherwise."""
    if t >= _EPOCH_LIKE:
        return datetime.fromtimestamp(t, UTC).strftime("%H:%M:%S.%f")[:-3] + " UTC"
    return f"{t:.3f} s"


def describe_gap(gap: MeasurementGap) -> str:
    """``/audio: not measured from A to B (reason)``, or ``... since A`` while it is open."""
    when = (f"since {moment(gap.start)}" if gap.end is None
            else f"from {moment(gap.start)} to {moment(gap.end)}")
    return f"{gap.subject()}: not measured {when} ({gap.reason})"


class Unmeasured:
    """The gaps one observer was told of.

    ``ended`` is the end of the latest closed gap: data stamped before it belongs to a gap
    (a reader catching up after a pause) and is not used. Several gaps may be open at once
    (a topic's own and the black box's pause); the observer is unjudged while any is.
    """

    __slots__ = ("_open", "ended", "last_start", "reason")

    def __init__(self) -> None:
        self._open: dict[tuple[float, str | None, str | None], MeasurementGap] = {}
        self.ended = -math.inf
        self.last_start = -math.inf
        self.reason = ""

    def apply(self, gap: MeasurementGap) -> bool:
        """Take ``gap`` in; ``True`` when it ends one (the observer then starts afresh)."""
        key = (gap.start, gap.topic, gap.node)
        if gap.end is None:
            self._open[key] = gap
            return False
        self._open.pop(key, None)
        self.ended = max(self.ended, gap.end)
        self.last_start = gap.start
        self.reason = gap.reason
        return True

    @property
    def open(self) -> bool:
        return bool(self._open)

    def covers(self, t: float) -> bool:
        """Whether data stamped ``t`` falls in a gap (before the last end, or in an open one)."""
        if t < self.ended:
            return True
        return any(t >= g.start for g in self._open.values())

    def observation(self, now: float, observer: str, resource: Resource) -> Observation | None:
        """``NOT_AVAILABLE`` "not measured since ..." while a gap is open, else ``None``."""
        if not self._open:
            return None
        gap = min(self._open.values(), key=lambda g: g.start)
        return Observation(now, observer, resource, Code.NOT_AVAILABLE,
                           values={UNMEASURED: gap.start},
                           message=f"not measured since {moment(gap.start)} ({gap.reason}); "
                                   "no verdict until measurement resumes")
