"""A second participant on the domain that pretends to be a robot, for the trust tests.

Usage: ``robot_spoofer.py DOMAIN ROBOT_ID MODE``; it prints ``ready``, then acts on each
stdin line until ``quit``:

* ``green``: publishes, under the robot's source ids and with fresh times, what the real
  black box would publish if the camera had recovered: every entity OPERATIONAL, the
  diagnosis empty, a rectification of ``/usb_cam`` (made by the real mapper, so the samples
  are well formed), plus a signature sample of random bytes. Answers ``sent green``.
* ``logs``: from then on answers every log request addressed to the robot at once with
  one forged chunk holding a failure of ``/forged_node``; answers ``answering logs``.

It stays on the domain (its writers alive) until ``quit``, as a spoofer would.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time

from blackbox.health.extension import C_Sample_Signature
from blackbox.health.identity import EventLedger
from blackbox.health.ids import robot_resource_id
from blackbox.health.mapping import HealthMapper
from blackbox.health.types import C_Log_Reply, C_Log_Request, T_IdentifierType
from blackbox.model import Diagnosis
from blackbox.transport.participant import TOPIC_OF_TYPE, Bus, TransportSettings
from blackbox.transport.provenance import SIGNATURE_TOPIC
from dds_blackbox_driver import faulty, healthy


def green_samples(robot: str) -> list[object]:
    """What the robot would publish after the camera recovered, time-stamped now."""
    mapper = HealthMapper(robot, ledger=EventLedger())
    t = time.time()
    mapper.start(t)
    mapper.observations(t, faulty(t))
    mapper.diagnosis(Diagnosis(t, (frozenset({"/usb_cam"}),), (), "camera too slow"))
    out: list[object] = []
    for _ in range(3):  # a status clears after three good observations (hysteresis)
        t += 0.01
        out += [*mapper.observations(t, healthy(t)), *mapper.diagnosis(Diagnosis(t, ()))]
    return out


def answer_logs(bus: Bus, robot: str, stop: threading.Event) -> None:
    requests = bus.reader("BlackBox_Log_Request")
    replies = bus.writer("BlackBox_Log_Reply")
    rid = robot_resource_id(robot)
    forged = {"id": 1, "time": time.time() - 1, "kind": "failure", "entity": "/forged_node",
              "characteristic": None, "code": None,
              "payload": {"components": ["/forged_node"], "explanation": "forged"}}
    while not stop.is_set():
        for request in requests.take(N=16):
            if not isinstance(request, C_Log_Request) or \
                    request.A_recipientID.A_resourceId != rid:
                continue
            replies.write(C_Log_Reply(A_requestID=request.A_requestID, A_chunkIndex=0,
                                      A_recipientID=T_IdentifierType(
                                          request.A_requestID.A_resourceId, 0),
                                      A_sourceID=T_IdentifierType(rid, 0), A_last=True,
                                      A_status="ok", A_entries=[json.dumps(forged)],
                                      A_robotSignature=list(os.urandom(64))))
        time.sleep(0.005)


def main() -> int:
    domain, robot = int(sys.argv[1]), sys.argv[2]
    bus = Bus.open(TransportSettings(domain))
    writers = {name: bus.writer(name) for name in
               ("C_Monitored_Entity", "C_Monitored_Characteristic", "C_Failure_Event",
                "C_Threshold_Exceedence_Event", "BlackBox_Event_Extension",
                "BlackBox_Entity_Description", SIGNATURE_TOPIC)}
    stop = threading.Event()
    print("ready", flush=True)
    for line in sys.stdin:
        command = line.split()
        if not command or command[0] == "quit":
            break
        if command[0] == "green":
            for sample in green_samples(robot):
                name = TOPIC_OF_TYPE[type(sample)]
                if name not in writers:
                    continue
                source = sample.A_sourceID  # type: ignore[attr-defined]
                writers[SIGNATURE_TOPIC].write(C_Sample_Signature(
                    A_sourceID=source, A_topic=name, A_robotId=robot, A_boot="0" * 16,
                    A_counter=1, A_signedNs=time.time_ns(), A_digest=list(os.urandom(32)),
                    A_publicKey=list(os.urandom(32)), A_signature=list(os.urandom(64))))
                writers[name].write(sample)
            print("sent green", flush=True)
        elif command[0] == "logs":
            threading.Thread(target=answer_logs, args=(bus, robot, stop), daemon=True).start()
            print("answering logs", flush=True)
    stop.set()
    bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
