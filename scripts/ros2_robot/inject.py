#!/usr/bin/env python3
"""Inject faults into the thesis robot on ROS 2 and write the ground truth.

    inject.py --domain 42 --truth truth.jsonl [--duration 300] [--seed 1]
              [--kinds kill,stall,rate,offset,scale] [--mean-gap 20] [--length 5:15]
    inject.py --domain 42 --truth truth.jsonl --schedule faults.json

Starts the three rclpy thesis nodes (see ``robot.py``) on ``--domain``, then injects one
fault at a time on the real processes, separated by random gaps; the same kinds, random
draws and ground-truth format (``{start, end, kind, component, node, params}``, wall-clock
times) as ``scripts/ros1_robot/inject.py``:

- ``kill`` (node): SIGKILL; the node is started again at the end of the fault.
- ``stall`` (topic): SIGSTOP of the publishing node, SIGCONT at the end.
- ``rate`` (topic): the publisher's ``rate`` parameter is set to ``hz``, then restored.
- ``offset`` / ``scale`` (``/signal``): the signal generator's ``offset``/``scale``.

Parameters are set through the nodes' ROS 2 parameter services by a node of this script's
own (``/blackbox_test_injector``).

With ``--schedule`` (a JSON list of ``{kind, component, start, end, params}``, offsets in
seconds) it prints ``ready`` and the pids once every node is in the graph, reads the start
instant (wall-clock seconds) from a line on stdin and injects the schedule from then on,
as the ROS 1 injector does for ``blackbox evaluate --source ros2``. A fault's ground-truth
line is written when it begins (``end: null``) and again when it ends.
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import sys
import time
from pathlib import Path
from typing import Any

from robot import NODES, TOPICS, ParameterClient, ThesisRobot2

sys.path.append(str(Path(__file__).resolve().parent.parent))  # scripts/: the shared module
from fault_injection import (
    DEFAULT_RATES,
    ActiveFault,
    add_campaign_arguments,
    chosen_kinds,
    run_random,
    run_schedule,
    stop_on_signals,
)

KINDS = ("kill", "stall", "rate", "offset", "scale")
SET_ATTEMPTS = 3


class Injector:
    """Begins and ends faults on a running :class:`ThesisRobot2`, logging ground truth."""

    def __init__(self, robot: ThesisRobot2, params: ParameterClient,
                 truth: Path | None = None) -> None:
        self.robot = robot
        self.params = params
        self.truth = truth
        self.records: list[dict[str, Any]] = []

    def begin(self, kind: str, component: str, **params: float) -> ActiveFault:
        if kind == "kill":
            node = _check(component, NODES)
            self.robot.kill(node, signal.SIGKILL)
        elif kind == "stall":
            node = TOPICS[_check(component, TOPICS)]
            self.robot.kill(node, signal.SIGSTOP)
        elif kind == "rate":
            node = TOPICS[_check(component, TOPICS)]
            hz = params["hz"] if "hz" in params else DEFAULT_RATES[component] * params["factor"]
            self._set(node, rate=float(hz))
        elif kind in ("offset", "scale"):
            if component != "/signal":
                raise ValueError(f"{kind} acts on /signal, not {component}")
            node = TOPICS[component]
            key = "value" if kind == "offset" else "factor"
            self._set(node, **{kind: float(params[key])})
        else:
            raise ValueError(f"unknown fault kind {kind!r}; expected one of {', '.join(KINDS)}")
        fault = ActiveFault(kind, component, node, time.time(), dict(params))
        self._write(fault.record(None))
        return fault

    def end(self, fault: ActiveFault) -> dict[str, Any]:
        end = time.time()
        if fault.kind == "kill":
            self.robot.start_node(fault.node)
        elif fault.kind == "stall":
            self.robot.kill(fault.node, signal.SIGCONT)
        elif fault.kind == "rate":
            self._set(fault.node, rate=DEFAULT_RATES[fault.component])
        elif fault.kind == "offset":
            self._set(fault.node, offset=0.0)
        elif fault.kind == "scale":
            self._set(fault.node, scale=1.0)
        rec = fault.record(end)
        self.records.append(rec)
        self._write(rec)
        return rec

    def _set(self, node: str, **values: float) -> None:
        """Set parameters, asking again when a busy machine makes the service call time out
        (a lost call must not end the campaign and take the robot down with it)."""
        for attempt in range(SET_ATTEMPTS):
            try:
                self.params.set(node, **values)
                return
            except TimeoutError as exc:
                print(f"warning: {exc} (attempt {attempt + 1} of {SET_ATTEMPTS})",
                      file=sys.stderr, flush=True)
        raise TimeoutError(f"{node} did not take {values} in {SET_ATTEMPTS} attempts")

    def _write(self, rec: dict[str, Any]) -> None:
        """Append one ground-truth line now, so a crash loses nothing already injected."""
        if self.truth is not None:
            with self.truth.open("a", encoding="utf-8") as f:
                f.write(json.dumps(rec, sort_keys=True) + "\n")


def _check(name: str, known: dict[str, str]) -> str:
    if name not in known:
        raise ValueError(f"no {name}; expected one of {', '.join(known)}")
    return name


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain", type=int, required=True)
    add_campaign_arguments(parser, KINDS)
    parser.add_argument("--schedule", type=Path,
                        help="inject these faults (JSON list) from a start instant read on stdin")
    args = parser.parse_args(argv)
    kinds = chosen_kinds(parser, args, KINDS)
    stop = stop_on_signals()
    rng = random.Random(args.seed)
    args.truth.write_text("")
    robot = ThesisRobot2(args.domain) if args.log_dir is None else \
        ThesisRobot2(args.domain, log_dir=args.log_dir)

    params = ParameterClient(args.domain)
    injector = Injector(robot, params, args.truth)
    try:
        robot.start()
        for node in NODES:
            if not params.wait_for_node(node, 30):
                raise RuntimeError(f"{node} did not join the ROS 2 graph within 30 s")
        if args.schedule is not None:
            schedule = json.loads(args.schedule.read_text(encoding="utf-8"))
            print("ready " + json.dumps(robot.pids(), sort_keys=True), flush=True)
            line = sys.stdin.readline()
            if line.strip():
                run_schedule(injector, schedule, float(line), stop)
                while not stop["now"]:
                    time.sleep(0.1)
            return 0
        print(json.dumps(robot.pids(), sort_keys=True), flush=True)  # the robot is up
        run_random(injector, rng, kinds, (NODES, TOPICS), args, stop,
                   lambda node: params.wait_for_node(node, 30))
    except (RuntimeError, OSError, ValueError, TimeoutError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        robot.stop()
        params.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
