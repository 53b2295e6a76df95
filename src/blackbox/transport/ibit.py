"""The UCMS ``run_IBIT`` command: an initiated built-in test on request.

A station writes ``C_Monitored_Entity_run_IBIT`` with ``A_recipientID`` set to one of the
robot's entities (the robot itself for everything). The black box marks its entities
``A_bitInProgress``, evaluates every observer now, publishes the resulting characteristics
and events like any others, clears the flag and answers with a ``C_IBIT_Result`` carrying
the command's reference number and the entity's health after the test.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable

from blackbox.health.ids import SourceIds, stable_int
from blackbox.health.types import (
    C_IBIT_Result,
    C_Monitored_Entity_run_IBIT,
    T_IdentifierType,
    datetime_of,
)
from blackbox.transport.participant import Bus


class IbitService:
    """Takes run_IBIT commands addressed to one robot and answers them."""

    def __init__(self, bus: Bus, robot_id: str,
                 run: Callable[[C_Monitored_Entity_run_IBIT], C_IBIT_Result]) -> None:
        self.resource_id = SourceIds(robot_id).resource_id
        self.run = run
        self.reader = bus.reader("C_Monitored_Entity_run_IBIT")
        self.writer = bus.writer("BlackBox_IBIT_Result")

    def poll(self) -> int:
        count = 0
        for command in self.reader.take(N=8):
            if not isinstance(command, C_Monitored_Entity_run_IBIT):
                continue
            if command.A_recipientID.A_resourceId != self.resource_id:
                continue
            self.writer.write(self.run(command))
            count += 1
        return count


def request_ibit(bus: Bus, robot_id: str, *, entity: str = "",
                 timeout: float = 10.0) -> C_IBIT_Result | None:
    """Ask robot ``robot_id`` for a built-in test of ``entity`` ("" = the whole robot)."""
    ids = SourceIds(robot_id)
    writer = bus.writer("C_Monitored_Entity_run_IBIT")
    reader = bus.reader("BlackBox_IBIT_Result")
    station = T_IdentifierType(stable_int("station", secrets.token_hex(4)), 1)
    reference = secrets.randbits(31)
    recipient = ids.of("entity", entity)
    deadline = time.monotonic() + timeout
    while not writer.get_matched_subscriptions() and time.monotonic() < deadline:
        time.sleep(0.05)
    writer.write(C_Monitored_Entity_run_IBIT(A_recipientID=recipient, A_sourceID=station,
                                             A_referenceNum=reference,
                                             A_timeOfDataGeneration=datetime_of(time.time())))
    while time.monotonic() < deadline:
        for result in reader.take(N=16):
            if (isinstance(result, C_IBIT_Result) and result.A_referenceNum == reference
                    and result.A_recipientID == recipient):
                return result
        time.sleep(0.02)
    return None
