#!/usr/bin/env python3
"""Inject faults into the real thesis robot and write the ground truth.

    inject.py --port 11411 --truth truth.jsonl [--duration 300] [--seed 1]
              [--kinds kill,stall,rate,offset,scale] [--mean-gap 20] [--length 5:15]
    inject.py --port 11411 --truth truth.jsonl --schedule faults.json

Starts ``roscore`` and the three thesis nodes (see ``robot.py``), then injects faults on
the real processes. Without ``--schedule``: one fault at a time, separated by random gaps.
With ``--schedule`` (a JSON list of ``{kind, component, start, end, params}``, times in
seconds from a start instant; what ``blackbox evaluate --source ros1`` writes): prints
``ready`` and the pids, reads the start instant (wall-clock seconds) from a line on stdin,
then begins and ends every fault at its time; faults on different nodes may overlap.

- ``kill`` (node): SIGKILL; the node is started again at the end of the fault.
- ``stall`` (topic): SIGSTOP of the publishing node, SIGCONT at the end. A stopped process
  also stops answering its slave API, so it looks dead to anyone asking it.
- ``rate`` (topic): the publisher's ``~rate`` parameter is set to ``hz``, then restored.
  ``rate`` takes ``hz`` or ``factor`` (times the nominal rate).
- ``offset`` / ``scale`` (``/signal``): the signal generator's ``~offset``/``~scale``
  (parameters ``value`` / ``factor``); ``stuck``: ``~stuck`` freezes the value;
  ``drift``: ``~drift`` adds ``rate`` units per second.
- ``cpu_hog`` (node): ``~hog`` burns ``percent`` of one core in the node's own process;
  ``memory_growth`` (node): ``~leak`` keeps ``rate`` more bytes every second.

Ground truth is one JSON object per line in the simulator's format
(``{start, end, kind, component, node, params}``), times in wall-clock seconds
(``time.time()``, the ROS 1 source's clock), written as faults happen: a line with
``end: null`` when a fault begins, and the same fault with its end when it ends (the last
line of a fault is the one that counts; a fault with no end line lasted to the end).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from robot import NODES, TOPICS, ThesisRobot

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

KINDS = ("kill", "stall", "rate", "offset", "scale", "stuck", "drift", "cpu_hog",
         "memory_growth")
VALUE_PARAMS = {"offset": ("offset", "value", 0.0), "scale": ("scale", "factor", 1.0),
                "stuck": ("stuck", None, 0.0), "drift": ("drift", "rate", 0.0)}
"""Value fault kind -> (parameter of the signal generator, fault parameter, healthy value)."""
NODE_PARAMS = {"cpu_hog": ("hog", "percent"), "memory_growth": ("leak", "rate")}


class Injector:
    """Begins and ends faults on a running :class:`ThesisRobot`, logging ground truth."""

    def __init__(self, robot: ThesisRobot, truth: Path | None = None) -> None:
        self.robot = robot
        self.truth = truth
        self.records: list[dict[str, Any]] = []
        self._lock = threading.Lock()

    def begin(self, kind: str, component: str, **params: float) -> ActiveFault:
        if kind == "kill":
            node = self._node(component)
            os.kill(self.robot.pid(node), signal.SIGKILL)
        elif kind == "stall":
            node = self._publisher(component)
            os.kill(self.robot.pid(node), signal.SIGSTOP)
        elif kind == "rate":
            node = self._publisher(component)
            hz = params["hz"] if "hz" in params else DEFAULT_RATES[component] * params["factor"]
            self.robot.set_param(f"{node}/rate", float(hz))
        elif kind in VALUE_PARAMS:
            if component != "/signal":
                raise ValueError(f"{kind} acts on /signal, not {component}")
            node = TOPICS[component]
            name, key, _ = VALUE_PARAMS[kind]
            self.robot.set_param(f"{node}/{name}", 1.0 if key is None else float(params[key]))
        elif kind in NODE_PARAMS:
            node = self._node(component)
            name, key = NODE_PARAMS[kind]
            self.robot.set_param(f"{node}/{name}", float(params[key]))
        else:
            raise ValueError(f"unknown fault kind {kind!r}; expected one of {', '.join(KINDS)}")
        fault = ActiveFault(kind, component, node, time.time(), dict(params))
        self._write(fault.record(None))
        return fault

    def end(self, fault: ActiveFault, restart_wait: bool = True) -> dict[str, Any]:
        end = time.time()
        if fault.kind == "kill":
            self.robot.nodes[fault.node].wait(timeout=5)
            self.robot.start_node(fault.node)
        elif fault.kind == "stall":
            os.kill(self.robot.pid(fault.node), signal.SIGCONT)
        elif fault.kind == "rate":
            self.robot.set_param(f"{fault.node}/rate", DEFAULT_RATES[fault.component])
        elif fault.kind in VALUE_PARAMS:
            name, _, healthy = VALUE_PARAMS[fault.kind]
            self.robot.set_param(f"{fault.node}/{name}", healthy)
        elif fault.kind in NODE_PARAMS:
            self.robot.set_param(f"{fault.node}/{NODE_PARAMS[fault.kind][0]}", 0.0)
        rec = fault.record(end)
        self.records.append(rec)
        self._write(rec)
        return rec

    def _write(self, rec: dict[str, Any]) -> None:
        """Append one ground-truth line now, so a crash loses nothing already injected."""
        if self.truth is None:
            return
        with self._lock, self.truth.open("a", encoding="utf-8") as f:
            f.write(json.dumps(rec, sort_keys=True) + "\n")
            f.flush()

    @staticmethod
    def _node(name: str) -> str:
        if name not in NODES:
            raise ValueError(f"no node {name}; expected one of {', '.join(NODES)}")
        return name

    @staticmethod
    def _publisher(topic: str) -> str:
        if topic not in TOPICS:
            raise ValueError(f"no topic {topic}; expected one of {', '.join(TOPICS)}")
        return TOPICS[topic]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", type=int, default=11311)
    add_campaign_arguments(parser, KINDS[:5])
    parser.add_argument("--schedule", type=Path,
                        help="inject these faults (JSON list) from a start instant read on stdin")
    args = parser.parse_args(argv)
    kinds = chosen_kinds(parser, args, KINDS)
    stop = stop_on_signals()
    rng = random.Random(args.seed)
    args.truth.write_text("")
    robot = ThesisRobot(args.port, log_dir=args.log_dir)
    injector = Injector(robot, args.truth)

    try:
        robot.start()
        if args.schedule is not None:
            schedule = json.loads(args.schedule.read_text(encoding="utf-8"))
            print("ready " + json.dumps(robot.pids(), sort_keys=True), flush=True)
            line = sys.stdin.readline()
            if line.strip():
                run_schedule(injector, schedule, float(line), stop)
                while not stop["now"]:
                    time.sleep(0.1)
            return 0
        print(json.dumps(robot.pids(), sort_keys=True), flush=True)
        run_random(injector, rng, kinds, (NODES, TOPICS), args, stop,
                   lambda node: robot.wait_registered([node]))
    except (RuntimeError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        robot.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
