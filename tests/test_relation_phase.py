"""A relation's blocks end at its verdicts (issue 22, round rel22b): the verdict given at
a second reports the block that ended at the last grid point before it, not one that
ended up to a block earlier wherever the first message happened to start the grid. A 1 s
block of a 1 Hz odometer's relation otherwise judged data up to a second staler than it
had, and its alarm outlived a GPS fault's end beyond the 2 s grace, naming the odometer."""

from __future__ import annotations

from blackbox.model import Code
from test_relations import RELATION, drive, relation

ONE_SECOND_BLOCKS = RELATION.replace("block: 10\n", "block: 20\n").replace(
    "fresh: 0.3\n", "fresh: 0.3\ndelay: 0.15\n")


def z_at(observations: list, t: float) -> float:
    o = next(o for o in observations if o.time == t)
    return float(o.values["imu_z_z"])


def test_the_verdict_after_an_offset_began_reports_a_block_of_the_offset() -> None:
    """The grid starts at 0.55 s (the first message); verdicts come each whole second. An
    offset of ten block noise from 35 s (the yaw rate crossing zero, well excited): the
    verdict at 36 s judges the block of grid points up to 35.8 s (the judged point is
    ``delay`` 0.15 s behind the tick), 17 of its 20 points faulty, not the block up to
    35.35 s with 7 of them."""
    obs = relation(ONE_SECOND_BLOCKS)
    healthy = drive(obs, 34.45, start=0.55)
    assert healthy[-1].code == Code.GENERAL_OK, healthy[-1].message
    faulty = drive(obs, 3.0, start=35.0, offset=0.1, seed=1)
    assert z_at(faulty, 36.0) >= 7.0, [(o.time, o.values) for o in faulty]


def test_the_verdict_after_an_offset_ended_reports_a_block_without_it() -> None:
    obs = relation(ONE_SECOND_BLOCKS)
    drive(obs, 29.45, start=0.55)
    faulty = drive(obs, 5.0, start=30.0, offset=0.1, seed=1)
    assert faulty[-1].code == Code.NO_STATE_FITS, faulty[-1].message
    after = drive(obs, 3.0, start=35.0, seed=2)
    assert abs(z_at(after, 36.0)) < 1.5, [(o.time, o.values) for o in after]


def test_a_restart_phases_the_blocks_again() -> None:
    """After a gap of more than the observer's restart limit the grid starts again from
    the next message, anywhere in a second; the next verdict phases its blocks again."""
    obs = relation(ONE_SECOND_BLOCKS)
    drive(obs, 20.0)
    drive(obs, 30.45, start=60.55)
    faulty = drive(obs, 3.0, start=91.0, offset=0.1, seed=1)
    assert z_at(faulty, 92.0) >= 7.0, [(o.time, o.values) for o in faulty]
