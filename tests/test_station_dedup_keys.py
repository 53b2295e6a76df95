"""The station's own diagnosis events (derived from entity states, no robot event id) are
keyed by time and content: distinct diagnoses in one millisecond are kept apart, while the
live and the logged copy of one diagnosis meet."""
from __future__ import annotations

from blackbox.station.follow import _diagnosis_key


def test_two_diagnoses_in_one_millisecond_have_different_keys() -> None:
    t = 1_700_000_000.1234
    assert _diagnosis_key(t, frozenset({"/a"})) != _diagnosis_key(t + 0.0002, frozenset())


def test_the_live_and_the_logged_copy_of_a_diagnosis_share_a_key() -> None:
    live = _diagnosis_key(1_700_000_000.1234, frozenset({"/b", "/a"}))
    logged = _diagnosis_key(1_700_000_000.1231, frozenset(["/a", "/b"]))
    assert live == logged
