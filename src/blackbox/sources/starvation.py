"""The measurement gaps a live source reports when the CPU was not there: the black box's
own threads starved (a gap of everything), or a robot process on this host starved by the
host (a gap of that node's watched topics, and the host reported saturated).

Shared by the ROS 1 and ROS 2 sources, which call :meth:`StarvationGaps.check` at every
``poll`` with the horizon they hand out; the waits come from
:class:`~blackbox.sources.cpu_wait.StarvationWatch` (``schedstat`` run-queue delays).
Why a run-queue wait and not a late message: a node that waits on the run queue wanted to
run and the host gave it no core, so its late messages are the host's load; a node stopped
(``SIGSTOP``, a stall) or hung waits for nothing and a dead one has no counters, so their
silence stays the robot's fault and is judged as before.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from blackbox.events import MeasurementGap
from blackbox.sources.cpu_wait import StarvationWatch, cpu_pressure

REPORT_AGAIN = 10.0
"""Seconds a node must go unstarved before its next starvation is reported again."""


@dataclass(frozen=True, slots=True)
class Starvation:
    """What one ``poll`` found: ``own`` the gap of everything when the black box was starved,
    ``gaps`` those of starved publishers' topics (closed, from the start of the wait window
    to now), ``saturated`` the operator's messages for newly starved nodes."""

    own: MeasurementGap | None = None
    gaps: list[MeasurementGap] = field(default_factory=list)
    saturated: list[str] = field(default_factory=list)


class StarvationGaps:
    """Turns run-queue waits into gaps; ``local_publishers`` is (node -> pid, node -> the
    watched topics it publishes) of the live publishers on this host, replaced whole by the
    source's graph thread."""

    def __init__(self, watch: StarvationWatch | None = None) -> None:
        self.watch = watch or StarvationWatch()
        self.local_publishers: tuple[dict[str, int], dict[str, tuple[str, ...]]] = ({}, {})
        self._reported: dict[str, float] = {}

    def check(self, floor: float, until: float, now: float) -> Starvation:
        """Waits since the previous check. ``floor``: the last horizon handed out (gaps
        never reach back before it: what was handed out stays); ``until``: this poll's
        horizon; ``now``: the source's time now. The gaps run from the start of the wait
        window to ``now``, so the late messages of the starved stretch are not judged."""
        watch = self.watch
        mono = time.monotonic()
        base = floor or until
        found = watch.own(mono)
        own = None if found is None else MeasurementGap(
            now, max(base, now - found.span), now, f"a thread of the black box waited "
            f"{found.waited:.3g} s for a CPU within {found.span:.3g} s (starved of CPU)",
            timing_only=True)
        pids, topics = self.local_publishers
        gaps: list[MeasurementGap] = []
        saturated: list[str] = []
        for node, starved in sorted(watch.nodes(pids, mono).items()):
            start = max(base, now - starved.span)
            reason = (f"the host starved {node} of CPU: it waited {starved.waited:.3g} s for "
                      f"a core within {starved.span:.3g} s; its messages came late by the "
                      "host's load, not by its own fault")
            last = self._reported.get(node)
            self._reported[node] = mono
            if last is None or mono - last > REPORT_AGAIN:
                pressure = cpu_pressure(watch.meter.proc)
                saturated.append(
                    f"host saturated: {reason}"
                    + ("" if pressure is None else
                       f" (CPU pressure: some task waited {pressure:g} % of the last 10 s)")
                    + "; its topics' timing is not judged while it lasts")
            gaps.extend(MeasurementGap(min(start, until), start, now, reason, topic=t,
                                       timing_only=True)
                        for t in topics.get(node, ()))
        return Starvation(own, gaps, saturated)
