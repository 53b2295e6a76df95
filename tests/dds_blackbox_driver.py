"""A scripted black box for the DDS tests: publishes through ``DdsHealthSink`` (and records
through the real recorder when ``--store`` is given), driven line by line on stdin.

Commands: ``ok`` (one round of healthy observations of the thesis robot), ``fault`` (the
camera's rate fails and the diagnosis names ``/usb_cam``), ``burst N`` (N faults and N
recoveries at once), ``unpublished N`` (as many, lost on the network), ``quit``. Each
command is answered with ``done <command>`` on stdout once written. ``--zenoh ENDPOINT``
publishes through a Zenoh router instead. Observation times are
wall-clock so that log requests by time range work. ``--key`` signs what it publishes.
"""

from __future__ import annotations

import argparse
import sys
import time

from blackbox.health.identity import EventLedger
from blackbox.model import Code, Diagnosis, Observation, Resource, State
from blackbox.transport.publisher import DdsHealthSink
from blackbox.transport.zenoh_bus import ZenohSettings

CAMERA = Resource(topic="/usb_cam/image_raw", publishers=("/usb_cam",))
AUDIO = Resource(topic="/audio", publishers=("/audio_capture",))
SIGNAL = Resource(topic="/signal", publishers=("/signal_generator",))


def healthy(t: float) -> list[Observation]:
    ok = (State(1, "ok"),)
    return [
        Observation(t, "hz", CAMERA, Code.GENERAL_OK, ok, {"period": 0.0667}),
        Observation(t, "hz", AUDIO, Code.GENERAL_OK, ok, {"period": 0.0333}),
        Observation(t, "hz", SIGNAL, Code.GENERAL_OK, ok, {"period": 0.0667}),
        Observation(t, "scores", SIGNAL, Code.GENERAL_OK, ok, {"score": 15.0}),
        Observation(t, "activated", Resource(node="/usb_cam"), Code.GENERAL_OK),
    ]


def faulty(t: float) -> list[Observation]:
    out = healthy(t)
    out[0] = Observation(t, "hz", CAMERA, Code.NO_STATE_FITS, (), {"period": 0.5},
                         "period 0.5 s fits no state")
    return out


def fast(t: float) -> list[Observation]:
    """The camera healthy in another state ("fast"): a change of state the robot announces
    as a numbered event."""
    out = healthy(t)
    out[0] = Observation(t, "hz", CAMERA, Code.GENERAL_OK, (State(2, "fast"),),
                         {"period": 0.0333})
    return out


def zenoh_settings(args: argparse.Namespace) -> ZenohSettings | None:
    if args.zenoh is None:
        return None
    return ZenohSettings((args.zenoh,), args.partition, root_ca=args.tls_ca)


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--robot", required=True)
    p.add_argument("--domain", type=int, required=True)
    p.add_argument("--partition", default="blackbox")
    p.add_argument("--store", default=None)
    p.add_argument("--allow", action="append", default=[], metavar="PUBFILE=RIGHTS",
                   help="trust this station key for RIGHTS (comma separated: logs,ibit)")
    p.add_argument("--key", default=None,
                   help="the robot's private key: sign every sample and reply; accepted "
                        "request nonces are kept in KEY.nonces across restarts")
    p.add_argument("--zenoh", default=None, metavar="ENDPOINT",
                   help="publish over Zenoh through this router instead of DDS")
    p.add_argument("--tls-ca", default=None, help="the CA of a tls/ router")
    args = p.parse_args()
    stations = []
    for item in args.allow:
        from pathlib import Path

        from blackbox.transport.auth import StationAccess, parse_public_key

        pub, rights = item.split("=")
        text = Path(pub).read_text()
        stations.append(StationAccess(text.split()[2], parse_public_key(text),
                                      frozenset(rights.split(","))))
    ledger = EventLedger()  # shared, as blackbox.app composes them
    recorder = None
    if args.store:
        from blackbox.record import Recorder
        from blackbox.record.settings import RecorderSettings

        recorder = Recorder(RecorderSettings(args.store, commit_interval=0.1),
                            robot_id=args.robot, ledger=ledger)
    from blackbox.transport.auth import AccessPolicy

    sink = DdsHealthSink(args.robot, domain_id=args.domain, partition=args.partition,
                         log_store_path=args.store, on_ibit=lambda: healthy(time.time()),
                         access=AccessPolicy.of(stations), ledger=ledger,
                         signing_key_file=args.key, zenoh=zenoh_settings(args))
    sinks = [s for s in (sink, recorder) if s is not None]  # the publisher assigns ids first
    print("ready", flush=True)
    for line in sys.stdin:
        command = line.strip()
        t = time.time()
        if command == "quit":
            break
        if command == "ok":
            for s in sinks:
                s.on_observations(t, healthy(t))
                s.on_diagnosis(Diagnosis(t, ()))
        elif command == "fault":
            obs = faulty(t)
            for s in sinks:
                s.on_observations(t, obs)
                s.on_diagnosis(Diagnosis(t, (frozenset({"/usb_cam"}),), (obs[0],),
                                         "camera publishes too slowly"))
        elif command.startswith("unpublished "):
            # N faults and recoveries whose samples are lost on the way (mapped and
            # numbered, never written): only the robot's log has them.
            for _ in range(int(command.split()[1])):
                for obs, diagnosis in ((faulty(t), True), (healthy(t), False)):
                    d = Diagnosis(t, (frozenset({"/usb_cam"}),), (obs[0],), "too slow") \
                        if diagnosis else Diagnosis(t, ())
                    sink.mapper.observations(t, obs)
                    sink.mapper.diagnosis(d)
                    if recorder is not None:
                        recorder.on_observations(t, obs)
                        recorder.on_diagnosis(d)
                    t = time.time()
        elif command == "unpublished-state":
            # A change of state whose samples are lost on the way (mapped and numbered,
            # never written): only the robot's log has it, as an observation row.
            obs = fast(t)
            sink.mapper.observations(t, obs)
            if recorder is not None:
                recorder.on_observations(t, obs)
        elif command.startswith("burst "):
            # N failures and N rectifications of /usb_cam as fast as they can be made:
            # many share a millisecond, each is a distinct event.
            for _ in range(int(command.split()[1])):
                for obs, diagnosis in ((faulty(t), True), (healthy(t), False)):
                    for s in sinks:
                        s.on_observations(t, obs)
                        s.on_diagnosis(Diagnosis(t, (frozenset({"/usb_cam"}),), (obs[0],),
                                                 "camera publishes too slowly")
                                       if diagnosis else Diagnosis(t, ()))
                    t = time.time()
        else:
            print(f"unknown {command}", flush=True)
            continue
        if recorder is not None:
            deadline = time.monotonic() + 5
            while (recorder.written == 0 or recorder.pending) and time.monotonic() < deadline:
                time.sleep(0.02)
        print(f"done {command}", flush=True)
    for s in sinks:
        s.close()
    print("closed", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
