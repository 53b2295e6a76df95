"""How an alarm of a learned relation or liveness check ends (issue 22), as specifications.

Page's CUSUM falls by only ``k`` a healthy block, so after a fault it wanders around ``h``
and a residual the fault left a little off keeps it failed for seconds: in a fault campaign
on `sim:diffdrive` most false-alarm episodes were such afterglows naming a neighbour of a
fault that had ended. Once in alarm, one block that looks healthy (``|z| < RECOVER_Z``) and
lowers the alarmed side brings both sides down to ``h / 2``: undecided, neither accusing nor
clearing.
"""

from __future__ import annotations

from blackbox.model import Code
from blackbox.observe.signals import RECOVER_Z, Cusum, CusumSpec
from test_relations import RELATION, drive, relation

SPEC = CusumSpec(k=0.5, h=10.0)


def plain_cusum_alarm_block(zs: list[float], spec: CusumSpec) -> int | None:
    """The block at which Page's two-sided CUSUM without a ceiling first reaches ``h``."""
    up = down = 0.0
    for i, z in enumerate(zs):
        up, down = max(0.0, up + z - spec.k), max(0.0, down - z - spec.k)
        if max(up, down) >= spec.h:
            return i
    return None


def test_the_first_alarm_comes_when_pages_cusum_says_so_whatever_the_recovery():
    # a slow drift: every block below RECOVER_Z, evidence piling up
    zs = [0.02 * i for i in range(200)]
    cusum = Cusum(SPEC)
    first = next(i for i, z in enumerate(zs) if cusum.update(z) >= SPEC.h)
    assert first == plain_cusum_alarm_block(zs, SPEC)
    assert max(zs[: first + 1]) < RECOVER_Z


def test_an_alarm_ends_with_the_first_healthy_looking_block_as_undecided():
    cusum = Cusum(SPEC)
    for _ in range(5):
        cusum.update(8.0)  # an offset of eight noise std
    assert cusum.alarm
    cusum.update(-1.5)  # healthy, a little off the other way: Page's CUSUM would stay up
    assert not cusum.alarm
    assert cusum.statistic == SPEC.h / 2


def test_a_fault_that_goes_on_keeps_the_alarm():
    cusum = Cusum(SPEC)
    for _ in range(5):
        cusum.update(8.0)
    for z in [1.5, 0.6, 2.5, 1.0] * 5:  # the offset shrinks to the edge of detection
        cusum.update(z)
        assert cusum.alarm, z
    for z in [-RECOVER_Z, -3.0] * 5:  # the fault turned round: the other side takes over
        cusum.update(z)
    assert cusum.alarm


def test_after_recovery_a_fault_still_there_needs_half_the_evidence_again():
    cusum = Cusum(SPEC)
    for _ in range(3):
        cusum.update(9.0)
    cusum.update(0.0)
    assert cusum.statistic == SPEC.h / 2
    blocks = 0
    while not cusum.alarm:
        cusum.update(1.5)  # a small offset, below RECOVER_Z
        blocks += 1
    assert blocks == 5  # (h / 2) / (1.5 - k)


def test_an_upward_cusum_takes_a_quiet_block_as_healthy():
    cusum = Cusum(SPEC, two_sided=False)
    for _ in range(3):
        cusum.update(9.0)  # a noise burst
    assert cusum.alarm
    cusum.update(-6.0)  # much quieter than healthy: not a noise burst
    assert not cusum.alarm


def test_a_relation_stops_failing_within_two_seconds_of_the_end_of_an_offset():
    obs = relation()
    drive(obs, 30.0)
    faulty = drive(obs, 10.0, start=30.0, offset=0.1, seed=1)
    assert faulty[-1].code == Code.NO_STATE_FITS
    after = drive(obs, 10.0, start=40.0, seed=2)
    assert after[1].code != Code.NO_STATE_FITS, [o.message for o in after[:3]]
    assert all(o.code != Code.NO_STATE_FITS for o in after[1:]), [o.message for o in after]


FOLLOWING = RELATION.replace("    span: [-2.0, 2.0]\n",
                             "    span: [-2.0, 2.0]\n    track: 2.5\n    track_rate: 0.004\n")
"""A relation that follows a moving bias (a battery voltage against its current) at up to
0.4 block noise a second: ten seconds of a fault move the followed bias by four."""


def test_a_followed_relation_recovers_within_a_few_seconds_of_its_signals_agreeing_again():
    """The followed bias moved during the offset; once the signals agree as they did before
    it, the relation stops failing as an unfollowed one does, instead of failing on for the
    tens of seconds the bias takes to come back at its bounded rate."""
    obs = relation(FOLLOWING)
    healthy = drive(obs, 30.0)
    assert healthy[-1].code == Code.GENERAL_OK, healthy[-1].message
    faulty = drive(obs, 10.0, start=30.0, offset=0.1, seed=1)
    assert faulty[-1].code == Code.NO_STATE_FITS, [o.message for o in faulty]
    after = drive(obs, 20.0, start=40.0, seed=2)
    assert all(o.code != Code.NO_STATE_FITS for o in after[2:]), [o.message for o in after]
    assert after[-1].code == Code.GENERAL_OK, after[-1].message


def test_a_followed_relation_keeps_failing_while_its_offset_goes_on():
    obs = relation(FOLLOWING)
    drive(obs, 30.0)
    faulty = drive(obs, 20.0, start=30.0, offset=0.1, seed=1)
    first = next(i for i, o in enumerate(faulty) if o.code == Code.NO_STATE_FITS)
    assert all(o.code == Code.NO_STATE_FITS for o in faulty[first:]), [o.message for o in faulty]
