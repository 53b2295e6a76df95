"""The station's own diagnosis events (derived from entity states; the robot numbers the
failures and rectifications a diagnosis causes, not the diagnosis) are keyed by the robot's
time of the diagnosis to the nanosecond and its components: every change of diagnosis is
kept, also many in one millisecond, while the live and the logged copy of one diagnosis
meet."""
from __future__ import annotations

import random

from blackbox.health.types import datetime_of, seconds_of
from blackbox.station.follow import _diagnosis_key


def test_two_diagnoses_in_one_millisecond_have_different_keys() -> None:
    t = 1_700_000_000.1234
    assert _diagnosis_key(t, frozenset({"/a"})) != _diagnosis_key(t + 0.0002, frozenset())


def test_the_same_diagnosis_reached_twice_in_one_millisecond_has_two_keys() -> None:
    t = 1_700_000_000.1234
    assert _diagnosis_key(t, frozenset({"/a"})) != _diagnosis_key(t + 0.00001, frozenset({"/a"}))


def test_the_live_and_the_logged_copy_of_a_diagnosis_share_a_key() -> None:
    rng = random.Random(25)
    for _ in range(10_000):
        logged = 1_790_000_000 + rng.random() * 1e8  # the float the recorder stored
        live = seconds_of(datetime_of(logged))  # what the UCMS sample's time decodes to
        components = frozenset(rng.sample(["/a", "/b", "/c"], rng.randint(0, 3)))
        assert _diagnosis_key(live, components) == \
            _diagnosis_key(logged, frozenset(sorted(components)))
