"""The UCMS ``run_IBIT`` command: an initiated built-in test on request.

A station writes ``C_Monitored_Entity_run_IBIT`` with ``A_recipientID`` set to one of the
robot's entities (the robot itself for everything). The black box marks its entities
``A_bitInProgress``, evaluates every observer now, publishes the resulting characteristics
and events like any others, clears the flag and answers with a ``C_IBIT_Result`` carrying
the command's reference number and the entity's health after the test.

A built-in test makes the robot work, so it runs only for the stations the robot's
configuration allows (:mod:`blackbox.transport.auth`): they send the same command signed,
as ``C_IBIT_Request`` on ``BlackBox_IBIT_Request``. The plain UCMS command carries no
signature and is answered only where the configuration grants ``ibit`` to unsigned
requests; otherwise the answer's report says ``refused: <reason>`` and nothing runs.

A robot with a key signs its results (:mod:`blackbox.transport.provenance`); a station
given the robot's key ignores results it did not sign.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from blackbox.health.ids import SourceIds, stable_int
from blackbox.health.types import (
    C_IBIT_Request,
    C_IBIT_Result,
    C_Monitored_Entity_run_IBIT,
    T_DateTimeType,
    T_HealthStatus,
    T_IdentifierType,
    datetime_of,
)
from blackbox.transport.auth import (
    AccessPolicy,
    RequestSigner,
    RequestVerifier,
    from_wire,
    to_wire,
)
from blackbox.transport.participant import HealthBus, matched_both_ways
from blackbox.transport.provenance import SampleSigner, reply_signed_by
from blackbox.transport.resend import RecentAnswers, Resend

RESULT_TOPIC = "BlackBox_IBIT_Result"


def ibit_fields(command: C_Monitored_Entity_run_IBIT | C_IBIT_Request) -> dict[str, Any]:
    """What a station's signature covers: every field of the command."""
    t: T_DateTimeType = command.A_timeOfDataGeneration
    return {"recipient": [int(command.A_recipientID.A_resourceId),
                          int(command.A_recipientID.A_instanceId)],
            "source": [int(command.A_sourceID.A_resourceId),
                       int(command.A_sourceID.A_instanceId)],
            "reference": int(command.A_referenceNum),
            "time_ns": int(t.A_second) * 1_000_000_000 + int(t.A_nanoseconds)}


class IbitService:
    """Takes run_IBIT commands addressed to one robot and answers them."""

    def __init__(self, bus: HealthBus, robot_id: str,
                 run: Callable[[C_Monitored_Entity_run_IBIT], C_IBIT_Result],
                 verifier: RequestVerifier | None = None,
                 signer: SampleSigner | None = None) -> None:
        self.resource_id = SourceIds(robot_id).resource_id
        self.signer = signer
        self.robot_id = robot_id
        self.run = run
        self.verifier = verifier or RequestVerifier(robot_id, AccessPolicy())
        self.reader = bus.reader("C_Monitored_Entity_run_IBIT")
        self.signed_reader = bus.reader("BlackBox_IBIT_Request")
        self.readers = (self.reader, self.signed_reader)
        self.writer = bus.writer("BlackBox_IBIT_Result")
        self.refused = 0
        self._recent: RecentAnswers[tuple[int, int, int], C_IBIT_Result] = RecentAnswers()

    def poll(self) -> int:
        count = 0
        for command in [*self.reader.take(N=8), *self.signed_reader.take(N=8)]:
            if not isinstance(command, C_Monitored_Entity_run_IBIT | C_IBIT_Request):
                continue
            if command.A_recipientID.A_resourceId != self.resource_id:
                continue
            signed = from_wire(command.A_signed) if isinstance(command, C_IBIT_Request) \
                else None
            verdict = self.verifier.verify("ibit", ibit_fields(command), signed)
            if not verdict.allowed:
                self.refused += 1
                self._answer(self._refusal(command, verdict.reason))
                continue
            key = (int(command.A_sourceID.A_resourceId), int(command.A_referenceNum),
                   int(command.A_recipientID.A_instanceId))
            now = time.monotonic()
            if self._recent.crossing(key, now):
                continue  # the station's resend crossed our answer
            earlier = self._recent.get(key)
            if earlier is not None:  # our answer was lost: the same result, not a new test
                self._answer(earlier)
                self._recent.answered(key, now, earlier)
                continue
            plain = command if isinstance(command, C_Monitored_Entity_run_IBIT) else \
                C_Monitored_Entity_run_IBIT(
                    A_recipientID=command.A_recipientID, A_sourceID=command.A_sourceID,
                    A_referenceNum=command.A_referenceNum,
                    A_timeOfDataGeneration=command.A_timeOfDataGeneration)
            result = self.run(plain)
            self._answer(result)
            self._recent.answered(key, time.monotonic(), result)
            count += 1
        return count

    def _answer(self, result: C_IBIT_Result) -> None:
        if self.signer is not None:
            self.signer.seal(RESULT_TOPIC, result)
        self.writer.write(result)

    def _refusal(self, command: C_Monitored_Entity_run_IBIT | C_IBIT_Request,
                 reason: str) -> C_IBIT_Result:
        return C_IBIT_Result(A_recipientID=command.A_recipientID,
                             A_referenceNum=command.A_referenceNum,
                             A_sourceID=T_IdentifierType(self.resource_id, 0),
                             A_timeOfDataGeneration=datetime_of(time.time()),
                             A_healthStatus=T_HealthStatus.L_HealthStatus_UNKNOWN,
                             A_report=[f"refused: {reason}"])


def request_ibit(bus: HealthBus, robot_id: str, *, entity: str = "", timeout: float = 10.0,
                 signer: RequestSigner | None = None,
                 robot_key: Ed25519PublicKey | None = None,
                 on_forged: Callable[[C_IBIT_Result], None] | None = None,
                 ) -> C_IBIT_Result | None:
    """Ask robot ``robot_id`` for a built-in test of ``entity`` ("" = the whole robot).

    Signed with ``signer`` (default: the key named by ``$BLACKBOX_STATION_KEY``, if set);
    without a key the plain UCMS command is sent. A refusal is an answer whose report
    starts with ``refused:``. With ``robot_key`` only a result the robot signed counts;
    others go to ``on_forged`` and the wait goes on.
    """
    signer = signer if signer is not None else RequestSigner.from_environment()
    ids = SourceIds(robot_id)
    topic = "BlackBox_IBIT_Request" if signer is not None else "C_Monitored_Entity_run_IBIT"
    writer = bus.writer(topic)
    reader = bus.reader("BlackBox_IBIT_Result")
    station = T_IdentifierType(stable_int("station", signer.station if signer else
                                          secrets.token_hex(4)), 1)
    reference = secrets.randbits(31)
    recipient = ids.of("entity", entity)
    deadline = time.monotonic() + timeout
    while not matched_both_ways(writer, reader) and time.monotonic() < deadline:
        time.sleep(0.05)
    command = C_Monitored_Entity_run_IBIT(A_recipientID=recipient, A_sourceID=station,
                                          A_referenceNum=reference,
                                          A_timeOfDataGeneration=datetime_of(time.time()))
    def signed() -> C_IBIT_Request | C_Monitored_Entity_run_IBIT:
        """The command, signed anew each time it is written (a nonce is taken once)."""
        if signer is None:
            return command
        return C_IBIT_Request(
            A_recipientID=recipient, A_sourceID=station, A_referenceNum=reference,
            A_timeOfDataGeneration=command.A_timeOfDataGeneration,
            A_signed=to_wire(signer.sign("ibit", robot_id, ibit_fields(command))))

    writer.write(signed())
    resend = Resend(time.monotonic())
    while time.monotonic() < deadline:
        if resend.due(time.monotonic()):
            writer.write(signed())  # nothing yet: the first may have gone to nobody
        for result in reader.take(N=16):
            if (isinstance(result, C_IBIT_Result) and result.A_referenceNum == reference
                    and result.A_recipientID == recipient):
                if robot_key is None or reply_signed_by(robot_key, robot_id, RESULT_TOPIC,
                                                        result):
                    return result
                if on_forged is not None:
                    on_forged(result)
        time.sleep(0.02)
    return None
