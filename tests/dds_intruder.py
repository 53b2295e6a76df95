"""Writes what no black box would for the DDS robustness test: a foreign type on a UCMS
topic name, and well-formed UCMS samples full of nonsense (unknown references, NaN,
huge strings; an out-of-range status is impossible: Cyclone refuses to encode it).

No ``from __future__ import annotations``: the IDL machinery needs real annotations.
"""


import sys
import time
from dataclasses import dataclass

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import int32
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from blackbox.health.types import (
    C_Failure_Event,
    C_Monitored_Characteristic,
    C_Threshold_Exceedence_Event,
    T_IdentifierType,
)
from blackbox.transport.participant import Bus, TransportSettings
from blackbox.transport.qos import EVENT, STATE


@dataclass
class Foreign(IdlStruct, typename="Foreign.Thing"):
    x: int32
    text: str


def main() -> int:
    bus = Bus.open(TransportSettings(int(sys.argv[1])))
    foreign = DataWriter(bus.publisher, Topic(bus.participant, "C_Monitored_Entity", Foreign),
                         STATE)
    chars = DataWriter(bus.publisher, bus.topic("C_Monitored_Characteristic"), STATE)
    tee = DataWriter(bus.publisher, bus.topic("C_Threshold_Exceedence_Event"), EVENT)
    fail = DataWriter(bus.publisher, bus.topic("C_Failure_Event"), EVENT)
    deadline = time.monotonic() + 5
    while not chars.get_matched_subscriptions() and time.monotonic() < deadline:
        time.sleep(0.05)
    nobody = T_IdentifierType(12345, 999)
    foreign.write(Foreign(7, "not an entity"))
    chars.write(C_Monitored_Characteristic(A_sourceID=nobody, A_value=float("nan"),
                                           A_monitoredEntity_sourceID=T_IdentifierType(1, 2)))
    tee.write(C_Threshold_Exceedence_Event(A_sourceID=T_IdentifierType(12345, 5),
                                           A_measuredValue=float("inf"),
                                           A_concernedCharacteristic_sourceID=nobody))
    fail.write(C_Failure_Event(A_sourceID=T_IdentifierType(12345, 6),
                               A_failureDescription="x" * 100_000,
                               A_monitoredEntity_sourceID=T_IdentifierType(-1, -1)))
    time.sleep(1.0)
    bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
