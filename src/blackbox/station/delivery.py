"""Whether the station gets everything the robots send, said to the operator.

Samples can be lost before the station stores them in two places it can see: the bus drops
them (a DDS reader's ``sample lost`` and ``sample rejected`` statuses, a Zenoh reader's full
queue), or the station reads slower than the fleet writes (every take comes back full, so a
backlog grows until the bus drops the oldest). Either is shown as a problem on every page
and counted for ``/metrics``, so a fleet that outgrew its station is noticed by the operator
and not discovered later as holes in the data.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

CHECK_EVERY = 1.0
"""Seconds between two reads of the readers' loss counters (cheap, but not per sample)."""
BEHIND_AFTER = 5.0
"""Seconds of full takes after which the station says it cannot keep up."""


@dataclass
class DeliveryCounts:
    """Samples the bus dropped before the station could take them, per topic, since start."""

    lost: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    overflowed: dict[str, int] = field(default_factory=dict)

    def total(self) -> int:
        return sum(self.lost.values()) + sum(self.rejected.values()) + \
            sum(self.overflowed.values())


def _count(reader: Any, method: str) -> int:
    """A DDS status's running total (``0`` where the bus has no such status)."""
    get = getattr(reader, method, None)
    if get is None:
        return 0
    try:
        return int(get().total_count)
    except Exception:  # a closed reader or a bus without the status: nothing to say
        return 0


class DeliveryWatch:
    """Reads the readers' loss counters and the follower's backlog; reports changes with
    ``report(source, message)`` (the store's problems) and ``clear(source)``."""

    def __init__(self, report: Callable[[str, str], None],
                 clear: Callable[[str], None]) -> None:
        self._report = report
        self._clear = clear
        self.counts = DeliveryCounts()
        self._last_check = -float("inf")
        self._full_since: float | None = None
        self._told_behind = False
        self.behind_total = 0.0
        """Seconds the station spent behind the fleet, summed over the run."""
        self.coalesced = 0
        """Characteristic values the follower left out while behind, each for a newer
        value of its characteristic (:mod:`blackbox.station.coalesce`)."""

    def check(self, readers: Mapping[str, Any], now: float) -> None:
        """Read every reader's loss counters (at most every :data:`CHECK_EVERY` s)."""
        if now - self._last_check < CHECK_EVERY:
            return
        self._last_check = now
        before = self.counts.total()
        for topic, reader in readers.items():
            self.counts.lost[topic] = _count(reader, "get_sample_lost_status")
            self.counts.rejected[topic] = _count(reader, "get_sample_rejected_status")
            self.counts.overflowed[topic] = int(getattr(reader, "overflowed", 0) or 0)
        if self.counts.total() > before:
            worst = max(readers, key=lambda t: self.counts.lost.get(t, 0)
                        + self.counts.rejected.get(t, 0) + self.counts.overflowed.get(t, 0))
            self._clear("delivery")  # one line, with the running total
            self._report("delivery", f"{self.counts.total()} samples dropped by the bus "
                                     f"before the station could take them (most on {worst}); "
                                     "the fleet's data has holes")

    def took(self, full: bool, now: float, elapsed: float) -> None:
        """After a poll: ``full`` when some reader gave as many samples as asked (more were
        waiting); ``elapsed`` the poll's seconds."""
        if not full:
            if self._told_behind:
                self._clear("ingest")
                self._report("ingest-recovered", "the station keeps up with the fleet again")
            self._full_since = None
            self._told_behind = False
            return
        if self._full_since is None:
            self._full_since = now
        self.behind_total += elapsed
        if not self._told_behind and now - self._full_since >= BEHIND_AFTER:
            self._told_behind = True
            self._report("ingest", f"the station cannot keep up: samples have been waiting "
                                   f"for {now - self._full_since:.0f} s; the bus will drop "
                                   "the oldest")

    @property
    def behind(self) -> bool:
        return self._told_behind
