"""A station behind its fleet handles the newest value of each characteristic, and counts
the older ones it left out (``blackbox.station.coalesce``)."""

from __future__ import annotations

from blackbox.health.types import C_Monitored_Characteristic, T_IdentifierType
from blackbox.station.coalesce import newest_per_characteristic
from blackbox.transport.cdr_decoder import decoder_for


def value(robot: int, characteristic: int, v: float) -> C_Monitored_Characteristic:
    """A value as the station's reader hands it over: encoded by a robot, decoded."""
    sample = C_Monitored_Characteristic(A_sourceID=T_IdentifierType(robot, characteristic),
                                        A_value=v)
    decoded: C_Monitored_Characteristic = decoder_for(C_Monitored_Characteristic)(
        sample.serialize())
    return decoded


def test_the_newest_value_of_each_characteristic_is_kept_in_taking_order() -> None:
    backlog = [value(1, 10, 1.0), value(1, 11, 5.0), value(2, 10, 7.0), value(1, 10, 2.0),
               value(1, 10, 3.0), value(2, 10, 8.0)]
    kept, left_out = newest_per_characteristic(backlog)
    assert [(s.A_sourceID.A_resourceId, s.A_sourceID.A_instanceId, s.A_value)
            for s in kept] == [(1, 11, 5.0), (1, 10, 3.0), (2, 10, 8.0)]
    assert left_out == 3  # every value either handled or counted


def test_a_backlog_without_repeats_loses_nothing() -> None:
    backlog = [value(r, c, float(r * c)) for r in (1, 2, 3) for c in (10, 11)]
    kept, left_out = newest_per_characteristic(backlog)
    assert kept == backlog and left_out == 0
