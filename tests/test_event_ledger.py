"""The event ledger: one identity per event, sequences without holes, bounded memory."""
from __future__ import annotations

import pytest

from blackbox.health.identity import EventId, EventLedger


def test_the_second_consumer_of_an_event_gets_the_identity_the_first_assigned() -> None:
    ledger = EventLedger("0123456789abcdef")
    first = ledger.assign("failure", "/cam", 10.5)
    assert ledger.assign("failure", "/cam", 10.5) == first
    assert ledger.lookup("failure", "/cam", 10.5) == first
    assert ledger.lookup("failure", "/cam", 10.6) is None
    assert first == EventId("0123456789abcdef", 1)


def test_events_in_one_instant_are_numbered_without_holes_and_listed_in_order() -> None:
    ledger = EventLedger("0123456789abcdef")
    ids = [ledger.assign(kind, key, 3.0) for kind, key in
           [("failure", "/a"), ("exceedance", "/a"), ("rectification", "/b")]]
    assert [i.sequence for i in ids] == [1, 2, 3]
    assert ledger.last == 3
    assert ledger.at(3.0, ("failure", "rectification")) == [
        ("failure", "/a", ids[0]), ("rectification", "/b", ids[2])]
    assert ledger.at(4.0, ("failure",)) == []


def test_forgotten_assignments_leave_no_trace_in_lookups_by_time() -> None:
    ledger = EventLedger("0123456789abcdef", memory=16)
    for i in range(40):
        ledger.assign("failure", f"/n{i % 3}", float(i // 2))
    assert ledger.at(0.0, ("failure",)) == []
    recent = ledger.at(19.0, ("failure",))
    assert [ident.sequence for _, _, ident in recent] == [39, 40]
    assert ledger.last == 40


@pytest.mark.parametrize("text", ["", "0123456789abcdef-0", "0123456789ABCDEF-1", "x-1",
                                  "0123456789abcdef-01", "0123456789abcdef-1 "])
def test_identities_from_the_network_are_parsed_strictly(text: str) -> None:
    assert EventId.parse(text) is None
