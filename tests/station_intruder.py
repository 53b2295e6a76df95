"""Writes what a station must survive, for the station follower tests: a description that
claims a robot id not its own, samples under a resource id no robot named, oversized
strings and sequences under a real robot's resource id, non-finite values.

Usage: ``station_intruder.py DOMAIN ROBOT_ID``. No ``from __future__ import annotations``:
the IDL machinery needs real annotations.
"""

import sys
import time

from blackbox.health.extension import C_Entity_Description
from blackbox.health.ids import SourceIds
from blackbox.health.types import (
    C_Failure_Event,
    C_Monitored_Characteristic,
    C_Monitored_Entity,
    T_IdentifierType,
)
from blackbox.transport.participant import Bus, TransportSettings


def main() -> int:
    domain, robot = int(sys.argv[1]), sys.argv[2]
    ids = SourceIds(robot)
    bus = Bus.open(TransportSettings(domain))
    names = bus.writer("BlackBox_Entity_Description")
    entities = bus.writer("C_Monitored_Entity")
    chars = bus.writer("C_Monitored_Characteristic")
    failures = bus.writer("C_Failure_Event")
    deadline = time.monotonic() + 5
    while not failures.get_matched_subscriptions() and time.monotonic() < deadline:
        time.sleep(0.05)
    stranger = T_IdentifierType(12345, 7)
    # A resource id that never names itself.
    entities.write(C_Monitored_Entity(A_sourceID=stranger))
    chars.write(C_Monitored_Characteristic(A_sourceID=T_IdentifierType(12345, 8),
                                           A_value=1.0, A_monitoredEntity_sourceID=stranger))
    # A description claiming the real robot's id under another resource id (spoofing).
    names.write(C_Entity_Description(A_sourceID=T_IdentifierType(777, 1), A_robotId=robot,
                                     A_name="spoof", A_kind="robot"))
    # Under the real robot's resource id: an oversized entity, nonsense values.
    fake = ids.of("entity", "/intruder")
    names.write(C_Entity_Description(A_sourceID=fake, A_robotId=robot, A_name="n" * 50_000,
                                     A_kind="node", A_parent_sourceID=ids.robot()))
    entities.write(C_Monitored_Entity(
        A_sourceID=fake, A_monitoredCharacteristics_sourceID=[
            T_IdentifierType(ids.resource_id, i) for i in range(1, 20_000)]))
    chars.write(C_Monitored_Characteristic(A_sourceID=ids.of("characteristic", "x"),
                                           A_value=float("nan"), A_monitoredEntity_sourceID=fake))
    failures.write(C_Failure_Event(A_sourceID=ids.of("failure", "x"),
                                   A_failureDescription="d" * 100_000,
                                   A_causeDescription="c" * 100_000,
                                   A_monitoredEntity_sourceID=fake))
    time.sleep(1.0)
    bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
