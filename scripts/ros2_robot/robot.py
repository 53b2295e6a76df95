#!/usr/bin/env python3
"""Start the thesis robot on ROS 2: the three rclpy nodes on one domain, loopback only.

    robot.py --domain 42 [--pids FILE]

Prints the pids as JSON (and writes them to ``--pids``), then runs until interrupted and
stops everything it started. Tests, the fault injector and the benchmarks use
:class:`ThesisRobot2` directly; :class:`ParameterClient` changes a node's parameters at
run time (the ROS 2 way of the ROS 1 robot's ``setParam``).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
NODE_SCRIPT = HERE / "thesis_node.py"

NODES = {"/usb_cam": "camera", "/audio_capture": "audio", "/Signal_generator": "signal"}
"""Node name -> role argument of ``thesis_node.py``."""

TOPICS = {"/usb_cam/image_raw": "/usb_cam", "/audio": "/audio_capture",
          "/signal": "/Signal_generator"}
"""Topic -> publishing node."""


def ros2_env(domain_id: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a loopback-only ROS 2 (Kilted, Fast DDS) process on a domain."""
    env = dict(os.environ if base is None else base)
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               RMW_IMPLEMENTATION="rmw_fastrtps_cpp", AMENT_PREFIX_PATH=sys.prefix,
               PYTHONUNBUFFERED="1")
    return env


@dataclass
class ThesisRobot2:
    """The thesis nodes as real rclpy processes on ROS 2 domain ``domain_id``."""

    domain_id: int
    log_dir: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="ros2-robot-")))
    python: str = sys.executable
    nodes: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    @property
    def env(self) -> dict[str, str]:
        return ros2_env(self.domain_id)

    def start(self, names: list[str] | None = None) -> ThesisRobot2:
        for name in names or list(NODES):
            self.start_node(name)
        return self

    def start_node(self, name: str, *args: str) -> subprocess.Popen[bytes]:
        role = NODES.get(name, name.strip("/"))
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log = (self.log_dir / f"{name.strip('/').replace('/', '_')}.log").open("ab")
        proc = subprocess.Popen([self.python, str(NODE_SCRIPT), role, *args], env=self.env,
                                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        log.close()
        self.nodes[name] = proc
        return proc

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.nodes.items() if p.poll() is None}

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        proc = self.nodes[name]
        proc.send_signal(sig)
        if sig in (signal.SIGKILL, signal.SIGTERM, signal.SIGINT):
            proc.wait(timeout=10)

    def stop(self) -> None:
        for proc in self.nodes.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGCONT)
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 5
        for proc in self.nodes.values():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
        self.nodes.clear()

    def __enter__(self) -> ThesisRobot2:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class ParameterClient:
    """Sets parameters of remote nodes through their ROS 2 parameter services.

    It is an rclpy node of its own (``/blackbox_test_injector``), in a private context on
    the robot's domain: the robot sees it, like it sees ``ros2 param set``.
    """

    def __init__(self, domain_id: int) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.node import Node

        os.environ.update({k: v for k, v in ros2_env(domain_id).items()
                           if k.startswith(("ROS_", "RMW_", "AMENT_"))})
        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("blackbox_test_injector", context=self.context)
        self._clients: dict[str, Any] = {}

    def set(self, node: str, timeout: float = 10.0, **values: float) -> None:
        """Set ``values`` on ``node``; raises ``TimeoutError`` if the node does not answer."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter

        client = self._clients.get(node)
        if client is None:
            client = self._clients[node] = self.node.create_client(
                SetParameters, f"{node}/set_parameters")
        if not client.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f"{node}/set_parameters not available")
        request = SetParameters.Request()
        request.parameters = [Parameter(k, value=float(v)).to_parameter_msg()
                              for k, v in values.items()]
        future = client.call_async(request)
        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(self.node)
        executor.spin_until_future_complete(future, timeout_sec=timeout)
        executor.remove_node(self.node)
        if not future.done():
            raise TimeoutError(f"{node} did not answer set_parameters")

    def wait_for_node(self, name: str, timeout: float) -> bool:
        """Wait until ``name`` shows in this node's view of the graph (bounded)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            names = {f"{ns.rstrip('/')}/{n}" for n, ns in
                     self.node.get_node_names_and_namespaces()}
            if name in names:
                return True
            time.sleep(0.1)
        return False

    def close(self) -> None:
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.context)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", 0)))
    parser.add_argument("--pids", type=Path, default=None)
    args = parser.parse_args()
    robot = ThesisRobot2(args.domain).start()
    pids = robot.pids()
    print(json.dumps(pids), flush=True)
    if args.pids:
        args.pids.write_text(json.dumps(pids))
    try:
        while all(p.poll() is None for p in robot.nodes.values()):
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        robot.stop()


if __name__ == "__main__":
    main()
