"""An alarm ends in doubt (issue 22, round rel22b): a relation that failed clears its
signals again only after it has held for a second (``SETTLE_SECONDS``). Its recovery takes
the CUSUM to ``h/2`` with one healthy-looking block and the next can be under it, so it was
held, clearing its target, one verdict after failing, while a slower relation of the same
target (a GPS speed against a 1 Hz odometer) still saw the fault's last second and so
named its other signal: most of sim:skidsteer's remaining false positives."""

from __future__ import annotations

import math

from blackbox.model import Code
from blackbox.observe.observers.relation import SETTLE_SECONDS
from test_relations import drive, msg, relation


def test_a_relation_that_failed_is_undecided_for_a_verdict_before_it_clears_again() -> None:
    obs = relation()
    drive(obs, 30.0)
    faulty = drive(obs, 5.0, start=30.0, offset=0.1, seed=1)
    assert faulty[-1].code == Code.NO_STATE_FITS, faulty[-1].message
    after = drive(obs, 10.0, start=35.0, seed=2)
    first_ok = next(i for i, o in enumerate(after) if o.code == Code.GENERAL_OK)
    assert first_ok >= 1, [(o.time, o.message) for o in after]
    assert all(o.code == Code.NOT_AVAILABLE for o in after[:first_ok]), \
        [(o.time, o.message) for o in after]
    assert any("settling after an alarm" in o.message for o in after[:first_ok]), \
        [(o.time, o.message) for o in after]
    assert after[first_ok].time <= 35.0 + 4 * SETTLE_SECONDS  # then it clears as before


def test_a_healthy_relation_clears_without_settling() -> None:
    obs = relation()
    healthy = drive(obs, 30.0)
    assert not any("settling" in o.message for o in healthy)
    assert healthy[-1].code == Code.GENERAL_OK


def test_an_alarm_does_not_outlive_a_blind_spell() -> None:
    """A fault ends while the relation cannot judge (the IMU silent for 1.5 s: stale, and
    shorter than the spell after which old evidence is dropped anyway); its residual then
    sits a little off (0.8 block noise, above the drift ``k`` 0.5, so no block looks calm
    enough to recover). Kept at ``h`` through the spell, the alarm went on naming the
    sensor; now the relation is undecided when judged again, and only new evidence fails
    it."""
    obs = relation()
    drive(obs, 30.0)
    faulty = drive(obs, 5.0, start=30.0, offset=0.1, seed=1)
    assert faulty[-1].code == Code.NO_STATE_FITS, faulty[-1].message
    for k in range(30):  # only /cmd for 1.5 s: /imu silent
        t = 35.0 + 0.05 * k
        obs.on_message(msg("/cmd", t, w=0.5 * math.sin(2 * math.pi * t / 7.0)))
    blind = obs.evaluate(36.0)[0]
    assert blind.code == Code.NOT_AVAILABLE and "stale" in blind.message, blind.message
    after = drive(obs, 4.0, start=36.5, offset=0.008, seed=4)
    judged = [o for o in after if o.values]
    assert judged, [(o.time, o.message) for o in after]
    assert judged[0].code == Code.NOT_AVAILABLE, [(o.time, o.message) for o in after]
    assert "undecided" in judged[0].message
