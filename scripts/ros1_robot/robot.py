#!/usr/bin/env python3
"""Start the real thesis robot: ``roscore`` and the three rospy nodes on one port.

    robot.py --port 11411 [--pids FILE]

Prints the pids as JSON (and writes them to ``--pids``), then runs until interrupted and
stops everything it started. Tests and the fault injector use :class:`ThesisRobot`
directly; it needs only the standard library, so it runs under any Python 3.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import xmlrpc.client
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
NODE_SCRIPT = HERE / "thesis_node.py"
ROS_PYTHON = "/usr/bin/python3"

NODES = {"/usb_cam": "camera", "/audio_capture": "audio", "/Signal_generator": "signal"}
"""Node name -> role argument of ``thesis_node.py``."""

TOPICS = {"/usb_cam/image_raw": "/usb_cam", "/audio": "/audio_capture",
          "/signal": "/Signal_generator"}
"""Topic -> publishing node."""


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now (for a master nobody else uses)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def ros_env(port: int, home: str, host: str = "127.0.0.1") -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(ROS_MASTER_URI=f"http://{host}:{port}", ROS_IP=host,
               ROS_HOSTNAME=host, ROS_HOME=home, PYTHONUNBUFFERED="1")
    return env


@dataclass
class ThesisRobot:
    """roscore plus the thesis nodes as real processes on ``host``:``port`` (loopback by
    default; tests on shaped links give an address inside a network namespace they made)."""

    port: int
    home: str = field(default_factory=lambda: tempfile.mkdtemp(prefix="ros1-robot-"))
    log_dir: Path | None = None
    host: str = "127.0.0.1"
    core: subprocess.Popen[bytes] | None = None
    nodes: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    @property
    def master_uri(self) -> str:
        return f"http://{self.host}:{self.port}"

    @property
    def env(self) -> dict[str, str]:
        return ros_env(self.port, self.home, self.host)

    def _log(self, name: str) -> int | None:
        directory = self.log_dir or Path(self.home)
        directory.mkdir(parents=True, exist_ok=True)
        return os.open(directory / f"{name.strip('/') or 'node'}.log",
                       os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)

    def start(self, timeout: float = 30.0) -> ThesisRobot:
        self.start_master(timeout)
        for name in NODES:
            self.start_node(name)
        self.wait_registered(list(NODES), timeout)
        return self

    def start_master(self, timeout: float = 30.0) -> None:
        fd = self._log("roscore")
        self.core = subprocess.Popen(["roscore", "-p", str(self.port)], env=self.env,
                                     stdout=fd, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        os.close(fd)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.core.poll() is not None:
                raise RuntimeError(f"roscore exited with {self.core.returncode}; "
                                   f"see {self.home}/roscore.log")
            try:
                names = self.system_node_names()
                if "/rosout" in names:
                    return
            except OSError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"roscore on port {self.port} did not come up in {timeout} s")

    def stop_master(self) -> None:
        if self.core is not None and self.core.poll() is None:
            _kill_group(self.core, signal.SIGINT)
        self.core = None

    def start_node(self, name: str, rate: float | None = None) -> subprocess.Popen[bytes]:
        cmd = [ROS_PYTHON, str(NODE_SCRIPT), NODES[name]]
        if rate is not None:
            cmd += ["--rate", str(rate)]
        fd = self._log(name)
        proc = subprocess.Popen(cmd, env=self.env, stdout=fd, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        os.close(fd)
        self.nodes[name] = proc
        return proc

    def stop_node(self, name: str) -> None:
        proc = self.nodes.pop(name, None)
        if proc is not None and proc.poll() is None:
            _kill_group(proc, signal.SIGINT)

    def pid(self, name: str) -> int:
        return self.nodes[name].pid

    def pids(self) -> dict[str, int]:
        out = {name: p.pid for name, p in self.nodes.items()}
        if self.core is not None:
            out["roscore"] = self.core.pid
        return out

    def master(self) -> xmlrpc.client.ServerProxy:
        return xmlrpc.client.ServerProxy(self.master_uri)

    def system_node_names(self) -> set[str]:
        _code, _, state = self.master().getSystemState("/robot_launcher")
        names: set[str] = set()
        for group in state:
            for _, members in group:
                names.update(members)
        return names

    def wait_registered(self, names: list[str], timeout: float = 30.0) -> None:
        """Wait until every node in ``names`` publishes or subscribes something."""
        deadline = time.monotonic() + timeout
        missing = set(names)
        while time.monotonic() < deadline:
            for name in names:
                proc = self.nodes.get(name)
                if proc is not None and proc.poll() is not None:
                    raise RuntimeError(f"{name} exited with {proc.returncode}; "
                                       f"see its log in {self.log_dir or self.home}")
            with contextlib.suppress(OSError):
                missing = set(names) - self.system_node_names()
            if not missing:
                return
            time.sleep(0.1)
        raise RuntimeError(f"nodes {sorted(missing)} did not register in {timeout} s")

    def set_param(self, key: str, value: float) -> None:
        code, msg, _ = self.master().setParam("/robot_launcher", key, value)
        if code != 1:
            raise RuntimeError(f"setParam {key}: {msg}")

    def stop(self) -> None:
        """Interrupt every node and the master at once, then wait for them (SIGKILL at 5 s)."""
        procs = list(self.nodes.values()) + ([self.core] if self.core is not None else [])
        self.nodes.clear()
        self.core = None
        for proc in procs:
            if proc.poll() is None:
                with contextlib.suppress(OSError):
                    os.killpg(proc.pid, signal.SIGCONT)
                    os.killpg(proc.pid, signal.SIGINT)
        deadline = time.monotonic() + 5.0
        for proc in procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(OSError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=5.0)

    def __enter__(self) -> ThesisRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _kill_group(proc: subprocess.Popen[bytes], sig: int, grace: float = 5.0) -> None:
    """Signal the process group, then SIGKILL it if it lingers."""
    with contextlib.suppress(OSError):
        os.killpg(proc.pid, sig)
    try:
        proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(OSError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=grace)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", type=int, default=11311, help="ROS master port")
    parser.add_argument("--pids", type=Path, help="also write the pids as JSON here")
    parser.add_argument("--log-dir", type=Path, help="node logs (default: a temporary ROS_HOME)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address the master and nodes advertise (default 127.0.0.1)")
    args = parser.parse_args(argv)
    robot = ThesisRobot(args.port, log_dir=args.log_dir, host=args.host)
    stop = {"now": False}

    def on_signal(signum: int, frame: object) -> None:
        stop["now"] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        robot.start()
        pids = json.dumps(robot.pids(), sort_keys=True)
        print(pids, flush=True)
        if args.pids:
            args.pids.write_text(pids + "\n")
        print(f"thesis robot up on {robot.master_uri}; Ctrl-C stops it", file=sys.stderr)
        while not stop["now"]:
            time.sleep(0.2)
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        robot.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
