"""Per-node CPU and memory for nodes running on this machine, via psutil.

psutil only sees local processes, so a node on another host gets a sample with ``None``
values and a reason instead of a silent zero. ``cpu_percent`` is percent of one core (a
node using two full cores reads 200), like ``top``.
"""

from __future__ import annotations

import socket
from functools import cache

import psutil

from blackbox.events import NodeInfo, ResourceSample


@cache
def _local_names() -> frozenset[str]:
    names = {"localhost", socket.gethostname(), socket.getfqdn()}
    for addrs in psutil.net_if_addrs().values():
        names.update(a.address.split("%")[0] for a in addrs
                     if a.family in (socket.AF_INET, socket.AF_INET6))
    return frozenset(names)


def is_local_host(host: str | None) -> bool:
    """Whether ``host`` (from a node's slave URI) is this machine."""
    if not host:
        return False
    if host.startswith("127.") or host == "::1" or host in _local_names():
        return True
    try:
        address = socket.gethostbyname(host)
    except OSError:
        return False
    return address.startswith("127.") or address in _local_names()


class ResourceSampler:
    """Samples nodes' processes; keeps one ``psutil.Process`` per pid so CPU % has a base."""

    def __init__(self) -> None:
        self._procs: dict[str, psutil.Process] = {}

    def sample(self, now: float, names: frozenset[str],
               nodes: dict[str, NodeInfo]) -> list[ResourceSample]:
        out: list[ResourceSample] = []
        for name in sorted(names):
            info = nodes.get(name)
            out.append(self._one(now, name, info))
        for name in list(self._procs):
            if name not in names:
                del self._procs[name]
        return out

    def _one(self, now: float, name: str, info: NodeInfo | None) -> ResourceSample:
        if info is None:
            self._procs.pop(name, None)
            return ResourceSample(now, name, None, None, f"node {name} is not in the ROS graph")
        if not info.alive or info.pid is None:
            self._procs.pop(name, None)
            return ResourceSample(now, name, None, None, f"node {name} is not running")
        if not is_local_host(info.host):
            return ResourceSample(now, name, None, None,
                                  f"node {name} runs on host {info.host}, not on the black "
                                  "box's machine; process resources are only measured for "
                                  "local nodes")
        proc = self._procs.get(name)
        try:
            if proc is None or proc.pid != info.pid:
                proc = self._procs[name] = psutil.Process(info.pid)
                proc.cpu_percent(None)
                return ResourceSample(now, name, None, float(proc.memory_info().rss),
                                      "CPU usage needs a second sample")
            with proc.oneshot():
                cpu = proc.cpu_percent(None)
                rss = proc.memory_info().rss
        except psutil.NoSuchProcess:
            self._procs.pop(name, None)
            return ResourceSample(now, name, None, None,
                                  f"pid {info.pid} of node {name} does not exist here (node "
                                  "in another pid namespace or just exited)")
        except psutil.AccessDenied:
            return ResourceSample(now, name, None, None,
                                  f"no permission to read process {info.pid} of node {name}")
        return ResourceSample(now, name, cpu, float(rss))
