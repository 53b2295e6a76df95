"""A robot network namespace and a black-box network namespace joined by a shaped veth pair.

Made and removed by the tests themselves (needs root and iproute2's ``ip`` and ``tc``).
Addresses live only inside these namespaces. Also used by benchmarks/constrained_link.py.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from blackbox.evaluate.real_campaign import stop_process_group

ROOT = Path(__file__).resolve().parent.parent
ROBOT_SCRIPT = ROOT / "scripts" / "ros1_robot" / "robot.py"
BLACKBOX = Path(sys.executable).with_name("blackbox")

WIFI_RATE = "8mbit"
"""About what the thesis's Wi-Fi carried: the 0.92 MB camera frames fell from 15 to 1 per
second over it (thesis 6.2.2), i.e. roughly 7-8 Mbit/s."""


class LinkUnavailable(Exception):
    """Namespaces or the shaped link cannot be made here (with the reason)."""


def _ip(*args: str) -> None:
    proc = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)
    if proc.returncode != 0:
        raise LinkUnavailable(f"`ip {' '.join(args)}` failed: {proc.stderr.strip()}")


@dataclass(frozen=True)
class ShapedLink:
    robot_ns: str
    box_ns: str
    robot_veth: str
    box_veth: str
    robot_addr: str
    box_addr: str
    rate: str

    def in_robot(self, *cmd: str) -> list[str]:
        return ["ip", "netns", "exec", self.robot_ns, *cmd]

    def in_box(self, *cmd: str) -> list[str]:
        return ["ip", "netns", "exec", self.box_ns, *cmd]

    def box_bytes(self) -> tuple[int, int]:
        """(received, sent) bytes on the black box's end of the link."""
        out = []
        for what in ("rx_bytes", "tx_bytes"):
            proc = subprocess.run(self.in_box("cat", f"/sys/class/net/{self.box_veth}/"
                                              f"statistics/{what}"),
                                  capture_output=True, text=True, timeout=10, check=True)
            out.append(int(proc.stdout.strip()))
        return out[0], out[1]


def why_not() -> str | None:
    """Why namespaces cannot be made here, or ``None``."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    for tool in ("ip", "tc"):
        if shutil.which(tool) is None:
            return f"needs iproute2's `{tool}`"
    if shutil.which("roscore") is None:
        return "needs Debian's ROS 1 (scripts/install-system-deps.sh)"
    return None


@contextlib.contextmanager
def shaped_link(rate: str = WIFI_RATE) -> Iterator[ShapedLink]:
    """Two fresh namespaces joined by a veth pair, both directions shaped with ``tc tbf``.
    Removed on exit whatever happened (removing a namespace removes its veth end)."""
    tag = f"{os.getpid() % 100000}"
    octet = os.getpid() % 250 + 1
    link = ShapedLink(f"bbrobot{tag}", f"bbbox{tag}", f"bbr{tag}", f"bbb{tag}",
                      f"10.231.{octet}.1", f"10.231.{octet}.2", rate)
    made: list[str] = []
    try:
        for ns in (link.robot_ns, link.box_ns):
            _ip("netns", "add", ns)
            made.append(ns)
        _ip("link", "add", link.robot_veth, "type", "veth", "peer", "name", link.box_veth)
        made.append(link.robot_veth)
        for veth, ns, addr in ((link.robot_veth, link.robot_ns, link.robot_addr),
                               (link.box_veth, link.box_ns, link.box_addr)):
            _ip("link", "set", veth, "netns", ns)
            _ip("-n", ns, "addr", "add", f"{addr}/30", "dev", veth)
            _ip("-n", ns, "link", "set", veth, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            proc = subprocess.run(["ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", veth,
                                   "root", "tbf", "rate", rate, "burst", "32kbit", "latency",
                                   "400ms"], capture_output=True, text=True, timeout=10)
            if proc.returncode != 0:
                raise LinkUnavailable(f"tc tbf on {veth}: {proc.stderr.strip()}")
        yield link
    finally:
        for ns in (link.robot_ns, link.box_ns):
            if ns in made:
                subprocess.run(["ip", "netns", "delete", ns], capture_output=True, timeout=10)
        if link.robot_veth in made:  # only left if it never moved into a namespace
            subprocess.run(["ip", "link", "delete", link.robot_veth], capture_output=True,
                           timeout=10)


@contextlib.contextmanager
def robot_in(link: ShapedLink, log_dir: Path, port: int = 11311) -> Iterator[dict[str, int]]:
    """The real thesis robot inside the robot namespace; yields its pids."""
    log_dir.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen(link.in_robot("/usr/bin/python3", str(ROBOT_SCRIPT), "--port",
                                          str(port), "--host", link.robot_addr, "--log-dir",
                                          str(log_dir)),
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            start_new_session=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line.startswith("{"):
            raise RuntimeError(f"robot did not start in {link.robot_ns}; see {log_dir}")
        yield json.loads(line)
    finally:
        stop_process_group(proc)


def set_param(link: ShapedLink, key: str, value: float, port: int = 11311) -> None:
    """``setParam`` on the robot's master, from inside the robot namespace."""
    code = (f"import xmlrpc.client as x; "
            f"print(x.ServerProxy('http://{link.robot_addr}:{port}').setParam('/test', "
            f"{key!r}, {value!r}))")
    subprocess.run(link.in_robot("/usr/bin/python3", "-c", code), check=True,
                   capture_output=True, timeout=20)


def start_black_box(link: ShapedLink, config: Path, out: Path, duration: float,
                    counters: bool = True, port: int = 11311) -> subprocess.Popen[bytes]:
    """``blackbox run`` inside the black box's namespace, writing observations and events."""
    source = f"ros1://{link.robot_addr}:{port}" + ("" if counters else "?counters=0")
    return subprocess.Popen(link.in_box(str(BLACKBOX), "run", "--quiet", "--source", source,
                                        "--config", str(config), "--duration", str(duration),
                                        "--observations", str(out / "obs.jsonl"),
                                        "--events", str(out / "events.jsonl")),
                            stdout=subprocess.DEVNULL, stderr=(out / "stderr.txt").open("w"))


def read_lines(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def wait_for_file(path: Path, timeout: float = 30.0) -> float:
    """Wall-clock time at which ``path`` first has a line (the black box is up)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and path.stat().st_size > 0:
            return time.time()
        time.sleep(0.1)
    raise RuntimeError(f"{path} stayed empty for {timeout} s")
