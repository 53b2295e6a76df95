"""A Zenoh router in its own process (``blackbox router``) for the tests: started on a free
loopback port, killed and started again on the same port to cut and restore the link."""

from __future__ import annotations

import queue
import socket
import subprocess
import sys
import threading
from collections.abc import Sequence

from station_support import dds_env

ROUTER_START_TIMEOUT = 60.0
"""``blackbox router`` imports the whole command line: slow on a loaded two-core machine."""


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class RouterProcess:
    """``blackbox router --listen ENDPOINT`` until :meth:`kill`."""

    def __init__(self, endpoint: str, extra: Sequence[str] = ()) -> None:
        self.endpoint = endpoint
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "blackbox", "router", "--listen", endpoint, *extra],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=dds_env())
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, args=(lines,), daemon=True).start()
        try:
            line = lines.get(timeout=ROUTER_START_TIMEOUT)
        except queue.Empty:
            self.kill()
            raise AssertionError(f"waited {ROUTER_START_TIMEOUT:g} s for the router on "
                                 f"{endpoint} to say it listens") from None
        if not line.startswith("router: listening"):
            self.kill()
            raise AssertionError(f"router on {endpoint} did not start: {line}")

    def _read(self, lines: queue.Queue[str]) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            lines.put(line.strip())
        lines.put("(router exited)")

    def kill(self) -> None:
        """Cut every link through this router at once (no goodbye to anybody)."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=10)
