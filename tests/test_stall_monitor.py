"""The stall monitor the timing tests use sees a process that is not run, and only then."""

from __future__ import annotations

import os
import signal
import time

from conftest import wait_until
from stall_monitor import StallMonitor


def test_a_stopped_monitor_counts_the_time_it_was_not_run() -> None:
    with StallMonitor() as monitor:
        assert monitor._process is not None  # its loop runs: it said so before enter returned
        start = time.time()
        os.kill(monitor._process.pid, signal.SIGSTOP)
        time.sleep(0.6)
        os.kill(monitor._process.pid, signal.SIGCONT)
        wait_until(lambda: monitor.stalls, "the monitor to report its stall")
        end = time.time()
    assert 0.5 <= monitor.stalled(start, end) <= end - start
    assert monitor.stalled(end + 1, end + 2) == 0.0
