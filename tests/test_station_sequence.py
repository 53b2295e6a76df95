"""What the station holds of a robot's numbered events, and which holes it reports."""
from __future__ import annotations

from blackbox.health.identity import EventId
from blackbox.station.sequence import EventSequences, Gap

BOOT = "0123456789abcdef"


def seen(seq: EventSequences, *numbers: int, now: float = 0.0) -> None:
    for n in numbers:
        seq.see(EventId(BOOT, n), event_time=100.0 + n, now=now)


def test_a_hole_is_reported_only_after_the_grace_period() -> None:
    seq = EventSequences(grace=2.0)
    seen(seq, 1, 2, 5, 6, 9)
    assert seq.gaps(now=1.0) == []
    assert seq.gaps(now=2.0) == [Gap(BOOT, 3, 4, 102.0, 0.0), Gap(BOOT, 7, 8, 106.0, 0.0)]
    assert seq.missing() == 4


def test_a_late_number_closes_its_hole() -> None:
    seq = EventSequences(grace=0.0)
    seen(seq, 1, 3, 2)
    assert seq.gaps(now=5.0) == []
    assert seq.missing() == 0


def test_giving_up_a_gap_counts_exactly_the_numbers_never_received() -> None:
    seq = EventSequences(grace=0.0)
    seen(seq, 1, 4, 6, 10)
    first = seq.gaps(now=1.0)[0]
    assert (first.first, first.last) == (2, 3)
    seq.give_up(first)
    assert seq.given_up == 2
    assert [(g.first, g.last) for g in seq.gaps(now=1.0)] == [(5, 5), (7, 9)]
    seq.give_up(Gap(BOOT, 5, 9, 0.0, 0.0))
    assert seq.given_up == 2 + 1 + 3
    assert seq.gaps(now=1.0) == [] and seq.missing() == 0


def test_the_first_number_heard_of_a_boot_opens_no_hole_below_it() -> None:
    seq = EventSequences(grace=0.0)
    seen(seq, 500, 501)
    assert seq.gaps(now=9.0) == [] and seq.missing() == 0
