"""Helpers shared by the crash tests: kill a process the hard way at a chosen moment."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable


def sigkill_after(proc: subprocess.Popen[bytes], started: Callable[[], None],
                  delay: float) -> float:
    """Wait until ``started()`` returns (it asserts the process got going), then ``delay``
    seconds more, then SIGKILL ``proc``; return the wall time of the kill. The process is
    always killed and reaped, also when ``started`` fails, and it must have died of the
    SIGKILL (not exited on its own before it)."""
    try:
        started()
        time.sleep(delay)
        killed_at = time.time()
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    return killed_at
