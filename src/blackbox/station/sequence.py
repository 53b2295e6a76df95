"""Which of a robot's events the station has, by sequence number, and which it misses.

Every event a black box publishes carries ``<boot>-<sequence>``
(:mod:`blackbox.health.identity`), numbered from 1 per start of the black box without
holes. A station that holds 5 and 7 of one boot misses 6: it fetches 6 from the robot's log
and, until then, tells the operator that the robot's record is incomplete. Events of one
boot travel on several DDS topics, so a number may overtake another briefly: a hole counts
only once it has stayed open for ``grace`` seconds.

Pure bookkeeping (time passed in); the follower serialises access.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from blackbox.health.identity import EventId

MAX_TRACKED = 100_000
"""Sequence numbers held above the first hole per boot at most (a forged huge number must
not grow memory): beyond it the oldest hole is given up."""


@dataclass(slots=True)
class Gap:
    """Sequence numbers ``first..last`` of ``boot`` not received; ``after`` is the time of
    the last event before the gap (where a log fetch starts)."""

    boot: str
    first: int
    last: int
    after: float
    opened: float

    @property
    def count(self) -> int:
        return self.last - self.first + 1


@dataclass(slots=True)
class _Boot:
    contiguous: int
    """Every number up to this one is held (or given up)."""
    time_of_contiguous: float
    above: dict[int, float] = field(default_factory=dict)
    """Numbers held beyond the first hole -> their event time."""
    hole_since: float | None = None


class EventSequences:
    """One robot's received sequence numbers per boot."""

    def __init__(self, grace: float = 2.0) -> None:
        self.grace = grace
        self._boots: dict[str, _Boot] = {}
        self.given_up = 0

    def see(self, ident: EventId, event_time: float, now: float) -> None:
        """Note that event ``ident`` (stamped ``event_time``) is stored."""
        b = self._boots.get(ident.boot)
        if b is None:
            # The first event heard of a boot: what came before is the backfill's job (a
            # station that starts late fetches the robot's recent past by time).
            self._boots[ident.boot] = _Boot(ident.sequence, event_time)
            return
        n = ident.sequence
        if n <= b.contiguous or n in b.above:
            return
        if n == b.contiguous + 1:
            b.contiguous, b.time_of_contiguous = n, event_time
            while b.contiguous + 1 in b.above:
                b.contiguous += 1
                b.time_of_contiguous = b.above.pop(b.contiguous)
            if not b.above:
                b.hole_since = None
            return
        b.above[n] = event_time
        if b.hole_since is None:
            b.hole_since = now
        if len(b.above) > MAX_TRACKED:
            self._give_up_first(b)

    def gaps(self, now: float) -> list[Gap]:
        """Holes open for at least ``grace`` seconds, oldest first."""
        out: list[Gap] = []
        for boot, b in self._boots.items():
            if not b.above or b.hole_since is None or now - b.hole_since < self.grace:
                continue
            expected = b.contiguous + 1
            after = b.time_of_contiguous
            for n in sorted(b.above):
                if n > expected:
                    out.append(Gap(boot, expected, n - 1, after, b.hole_since))
                expected, after = n + 1, b.above[n]
        return out

    def missing(self) -> int:
        """How many numbers are missing below the highest one held, over all boots."""
        total = 0
        for b in self._boots.values():
            if b.above:
                total += max(b.above) - b.contiguous - len(b.above)
        return total

    def give_up(self, gap: Gap) -> None:
        """Stop waiting for ``gap`` (its events are not in the robot's log either)."""
        b = self._boots.get(gap.boot)
        if b is None:
            return
        while b.above and b.contiguous < gap.last:
            b.contiguous += 1
            if b.contiguous in b.above:
                b.time_of_contiguous = b.above.pop(b.contiguous)
            else:
                self.given_up += 1
        while b.contiguous + 1 in b.above:
            b.contiguous += 1
            b.time_of_contiguous = b.above.pop(b.contiguous)
        b.hole_since = None if not b.above else b.hole_since

    def _give_up_first(self, b: _Boot) -> None:
        first_held = min(b.above)
        self.given_up += first_held - b.contiguous - 1
        b.contiguous = first_held
        b.time_of_contiguous = b.above.pop(first_held)
        while b.contiguous + 1 in b.above:
            b.contiguous += 1
            b.time_of_contiguous = b.above.pop(b.contiguous)
