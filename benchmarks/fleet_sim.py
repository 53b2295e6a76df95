"""Lightweight simulated black boxes: many robots in one process, one Zenoh session.

Why: a real black box is one process with one Zenoh session. A fleet of 1,000 of them cannot
run on the two cores that also run the station, so each robot used to be a full
``DdsHealthSink`` with a session of its own, and 4 processes of 250 such robots published
about 5 % of the stream. Here a robot keeps everything that makes its samples what they are
and drops what only costs:

* **the same samples**: each robot is the real ``DdsHealthSink`` (the real ``HealthMapper``,
  its ``EventLedger`` with ``<boot>-<sequence>`` identities, the precompiled CDR encoders,
  the same Zenoh writers: one advanced publisher per topic under
  ``blackbox/<robot_id>/<topic>``, its cache and heartbeats), so the bytes on the wire are
  a real robot's for the same health (``tests/test_zenoh_fleet_sim.py`` checks it through a
  real router into a real station);
* **one Zenoh session per process** (``ZenohBus.sharing``) instead of one per robot: the
  session, its threads and its link to the router are shared; nothing else is;
* **no services**: no log or IBIT service thread (the station's start-up backfill asks
  anyway and is unanswered, reported as a problem, as with the earlier simulated robots);
* **unsigned**: the station accepts unsigned health from robots it has not enrolled (its
  default); a real robot signs only with ``transport.key_file`` set;
* **precomputed observations**: each robot's observation lists (healthy, camera fault) are
  built once; a tick only restamps them (``dataclasses.replace`` of the time).

What stays per robot and per tick is the mapper (about 0.17 ms for the thesis robot's ten
observations on this machine) and 11 encoded and published characteristic values.

Robots tick at the thesis robot's rate (``--interval``, 1 s), spread evenly over the
interval (real robots are not synchronised), with a camera fault of ``--fault-length`` s
every ``--fault-every`` s per robot (phase shifted per robot): a failure diagnosis naming
``/usb_cam`` when it starts, a rectification when it ends. Each robot counts what it
published by kind; the last line printed is JSON: robot id -> counts and the times of its
fault transitions (for the watched robots).

    .venv/bin/python benchmarks/fleet_sim.py --zenoh tcp/127.0.0.1:7447 --ids r1,r2 --duration 30
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from blackbox.health.identity import EventLedger
from blackbox.health.types import (
    C_Failure_Event,
    C_Monitored_Characteristic,
    C_Threshold_Exceedence_Event,
)
from blackbox.model import Code, Diagnosis, Observation, Resource, State
from blackbox.transport.publisher import DdsHealthSink
from blackbox.transport.zenoh_bus import ZenohBus, ZenohSettings

COUNTED = {C_Monitored_Characteristic: "values", C_Threshold_Exceedence_Event: "exceedances",
           C_Failure_Event: "failures"}
CONNECT_TIMEOUT = 600.0
"""Seconds a fleet process waits for its session to reach the router before it gives up."""

_OK = (State(1, "ok"),)
_CAMERA = Resource(topic="/usb_cam/image_raw", publishers=("/usb_cam",))
_AUDIO = Resource(topic="/audio", publishers=("/audio_capture",))
_SIGNAL = Resource(topic="/signal", publishers=("/signal_generator",))


def thesis_observations(t: float, faulty: bool) -> list[Observation]:
    """The thesis robot's ten observers at ``t``: all well, or the camera too slow."""
    camera = (Observation(t, "hz", _CAMERA, Code.NO_STATE_FITS, (), {"period": 0.5},
                          "period 0.5 s fits no state") if faulty else
              Observation(t, "hz", _CAMERA, Code.GENERAL_OK, _OK, {"period": 0.0667}))
    return [camera,
            Observation(t, "timeout", _CAMERA, Code.GENERAL_OK),
            Observation(t, "hz", _AUDIO, Code.GENERAL_OK, _OK, {"period": 0.0333}),
            Observation(t, "timeout", _AUDIO, Code.GENERAL_OK),
            Observation(t, "hz", _SIGNAL, Code.GENERAL_OK, _OK, {"period": 0.0667}),
            Observation(t, "scores", _SIGNAL, Code.GENERAL_OK, _OK, {"score": 15.0}),
            *(Observation(t, "activated", Resource(node=n), Code.GENERAL_OK)
              for n in ("/usb_cam", "/audio_capture", "/signal_generator")),
            Observation(t, "resources", Resource(node="/usb_cam"), Code.GENERAL_OK, _OK,
                        {"cpu": 3.0, "memory": 2.1e7})]


_TEMPLATES = {faulty: thesis_observations(0.0, faulty) for faulty in (False, True)}


def restamped(t: float, faulty: bool) -> list[Observation]:
    """:func:`thesis_observations` at ``t`` from the precomputed lists (equal records)."""
    return [dataclasses.replace(o, time=t) for o in _TEMPLATES[faulty]]


class CountingSink(DdsHealthSink):
    """A real sink that counts what it published, by kind, for published vs stored."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.counts = {"values": 0, "exceedances": 0, "failures": 0, "rectifications": 0}
        super().__init__(*args, **kwargs)

    def _write(self, samples: Any) -> None:
        for sample in samples:
            before = self.written
            super()._write([sample])
            name = COUNTED.get(type(sample))
            if name and self.written > before:
                self.counts[name] += 1


@dataclass
class FaultSchedule:
    """A camera fault of ``length`` s every ``every`` s per robot, from ``start`` s on,
    shifted by ``shift`` s per robot so that faults start across the fleet all the time."""

    every: float = 30.0
    length: float = 6.0
    start: float = 0.0
    shift: float = 3.0

    def faulty(self, robot_index: int, elapsed: float) -> bool:
        phase = (elapsed + robot_index * self.shift) % self.every
        return phase < self.length and elapsed >= self.start


@dataclass
class LightRobot:
    """One simulated robot: a real sink on the process's shared session, its fault state
    and, if watched, when its faults started and ended."""

    sink: CountingSink
    index: int
    faulty: bool = False
    transitions: list[tuple[float, bool]] = field(default_factory=list)

    def tick(self, now: float, faulty: bool, watched: bool) -> None:
        self.sink.on_observations(now, restamped(now, faulty))
        if faulty and not self.faulty:
            self.sink.on_diagnosis(Diagnosis(now, (frozenset({"/usb_cam"}),),
                                             (restamped(now, True)[0],),
                                             "camera publishes too slowly"))
        elif self.faulty and not faulty:
            self.sink.on_diagnosis(Diagnosis(now, ()))
            self.sink.counts["rectifications"] += 1
        if faulty != self.faulty and watched:
            self.transitions.append((time.time(), faulty))
        self.faulty = faulty


class LightFleet:
    """``robot_ids`` on one Zenoh session to ``settings``' routers."""

    def __init__(self, settings: ZenohSettings, robot_ids: Sequence[str], *,
                 first_index: int = 0, clock: Callable[[], float] = time.time,
                 boot: str | None = None) -> None:
        # as a real robot's session: a peer that opens without a router and connects to it
        self.settings = dataclasses.replace(settings, router_optional=True)
        self.session = ZenohBus.open(self.settings, "fleet").session
        self.robots = [LightRobot(CountingSink(rid, zenoh=self.settings, clock=clock,
                                               ledger=EventLedger(boot) if boot else None,
                                               bus=ZenohBus.sharing(self.settings,
                                                                    self.session, rid)),
                                  first_index + i)
                       for i, rid in enumerate(robot_ids)]

    def connected(self) -> bool:
        return bool(list(self.session.info.routers_zid()))

    def run(self, duration: float, interval: float, schedule: FaultSchedule,
            watched: set[str], stop: threading.Event) -> None:
        """Each robot ticks every ``interval`` s, the fleet spread evenly over it."""
        start = time.time()
        end = start + duration
        n = len(self.robots)
        slot = interval / max(1, n)
        tick = 0
        while not stop.is_set() and time.time() < end:
            base = start + tick * interval
            for k, robot in enumerate(self.robots):
                due = base + k * slot
                if due >= end:
                    stop.wait(max(0.0, end - time.time()))
                    return
                if due > time.time() and stop.wait(due - time.time()):
                    return
                now = time.time()
                robot.tick(now, schedule.faulty(robot.index, now - start),
                           robot.sink.robot_id in watched)
            tick += 1

    def report(self) -> dict[str, dict[str, Any]]:
        return {r.sink.robot_id: {**r.sink.counts, "written": r.sink.written,
                                  "write_errors": r.sink.write_errors,
                                  "transitions": r.transitions} for r in self.robots}

    def close(self) -> None:
        for robot in self.robots:
            robot.sink.close()
        session: Any = self.session
        session.close()


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--zenoh", required=True, help="the router's endpoint, tcp/host:port")
    p.add_argument("--ids", required=True, help="robot ids, comma-separated")
    p.add_argument("--index", type=int, default=0, help="index of this fleet's first robot")
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--interval", type=float, default=1.0)
    p.add_argument("--fault-every", type=float, default=30.0)
    p.add_argument("--fault-length", type=float, default=6.0)
    p.add_argument("--fault-start", type=float, default=0.0)
    p.add_argument("--watch-ids", default="")
    p.add_argument("--wait-go", action="store_true",
                   help="after 'ready', tick only once a line comes on standard input")
    args = p.parse_args(argv)
    fleet = LightFleet(ZenohSettings((args.zenoh,)), args.ids.split(","),
                       first_index=args.index)
    deadline = time.monotonic() + CONNECT_TIMEOUT
    while not fleet.connected():
        if time.monotonic() > deadline:
            print(f"not connected to {args.zenoh} after {CONNECT_TIMEOUT:g} s", flush=True)
            return 1
        time.sleep(0.1)
    print("ready", flush=True)
    if args.wait_go:  # the benchmark says when: once the station has heard every robot
        sys.stdin.readline()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    cpu0 = time.process_time()
    fleet.run(args.duration, args.interval,
              FaultSchedule(args.fault_every, args.fault_length, args.fault_start),
              set(filter(None, args.watch_ids.split(","))), stop)
    cpu = time.process_time() - cpu0
    time.sleep(1.0)  # the last samples leave before the writers go
    out = fleet.report()
    fleet.close()
    print(json.dumps({"robots": out, "cpu_seconds": cpu}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
