"""Network exposure (issue 13): Cyclone's sockets stay on the configured interface, and a
flood of malformed datagrams cannot flood the log. Real processes, real sockets."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from isolation import fresh_domain
from station_support import dds_env
from test_dds_health import BlackBox

pytestmark = pytest.mark.dds


def udp_sockets(pid: int) -> list[str]:
    """Local addresses of a process's UDP sockets as ``ss`` shows them: a socket pinned to
    an interface reads ``0.0.0.0%lo:PORT``."""
    out = subprocess.run(["ss", "-H", "-u", "-a", "-n", "-p"], capture_output=True, text=True,
                         timeout=10).stdout
    return [line.split()[3] for line in out.splitlines() if f"pid={pid}," in line]


def wait_for_sockets(pid: int, count: int = 3) -> list[str]:
    deadline = time.monotonic() + 10
    while len(found := udp_sockets(pid)) < count:
        assert time.monotonic() < deadline, found
        time.sleep(0.1)
    return found


def test_the_black_box_receives_on_loopback_only(tmp_path: Path) -> None:
    box = BlackBox("thesis", fresh_domain(), store=tmp_path / "h.db")
    try:
        box.send("ok")
        found = wait_for_sockets(box.proc.pid)
    finally:
        box.stop()
    assert found, "the black box opened no UDP socket"
    for address in found:
        host = address.rsplit(":", 1)[0]
        assert host == "127.0.0.1" or host.endswith("%lo"), f"listening beyond loopback: {found}"


def test_a_flood_of_malformed_datagrams_gives_a_few_log_lines() -> None:
    domain = fresh_domain()
    listener = subprocess.Popen([sys.executable, "-m", "blackbox", "listen", "--domain",
                                 str(domain), "--json", "--duration", "6", "--backfill", "0"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=dds_env())
    try:
        wait_for_sockets(listener.pid)
        ports = {c.laddr.port for c in psutil.Process(listener.pid).net_connections(kind="udp")}
        header = b"RTPS\x02\x01\x01\x10" + os.urandom(12)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(1000):
                for port in ports:  # a DATA submessage whose lengths do not add up
                    s.sendto(header + b"\x15\x05\xff\xff" + os.urandom(40), ("127.0.0.1", port))
        _, err = listener.communicate(timeout=30)
    finally:
        listener.kill()
    lines = err.decode(errors="replace").splitlines()
    malformed = [line for line in lines if "malformed packet" in line]
    assert 1 <= len(malformed) <= 5, len(malformed)
    summary = [line for line in lines if "more malformed DDS packets" in line]
    assert summary and int(summary[0].split()[1]) > 100
    assert len(err) < 20_000
