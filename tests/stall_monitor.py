"""How long the machine stopped running processes, measured from a process of its own.

Timing bounds in tests (a graph snapshot every half second, no gap in a 15 Hz topic) hold
for the code under test, not for a machine that stops scheduling everything for most of a
second (2 cores, three test workers, real robots beside them). A separate process that
sleeps 10 ms at a time sees such a stall as its own late wake-ups; a test subtracts the
stall that overlaps a gap before it compares the gap with its bound. A separate process
and not a thread: a thread would also count time the code under test held the GIL, and
so excuse the very delays the test is there to catch.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from types import TracebackType

STEP = 0.01
"""Seconds the monitor sleeps between two looks at the clock."""
LATE = 0.03
"""A wake-up this much later than asked for is recorded as a stall."""
READY_TIMEOUT = 60.0
"""Seconds the monitor's interpreter may take to start on a loaded machine."""

_PROGRAM = f"""
import sys, time
step, late = {STEP!r}, {LATE!r}
last = time.time()
print("ready", flush=True)
while True:
    time.sleep(step)
    now = time.time()
    if now - last - step > late:
        print(f"{{last + step!r}} {{now!r}}", flush=True)
    last = now
"""


class StallMonitor:
    """Records the spans ``(start, end)`` (``time.time()``) during which a process of its
    own was not run although it asked to be; use it as a context manager."""

    def __init__(self) -> None:
        self.stalls: list[tuple[float, float]] = []
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self._process: subprocess.Popen[str] | None = None
        self._reader: threading.Thread | None = None

    def __enter__(self) -> StallMonitor:
        self._process = subprocess.Popen([sys.executable, "-c", _PROGRAM],
                                         stdout=subprocess.PIPE, text=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        # a stall before its loop runs (the interpreter still starting) would go unseen
        if not self._ready.wait(READY_TIMEOUT):
            self.__exit__(None, None, None)
            raise AssertionError(f"waited {READY_TIMEOUT:g} s for the stall monitor to start")
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if self._process is not None:
            time.sleep(2 * STEP)  # a stall at the very end is reported before the kill
            self._process.kill()
            self._process.wait(timeout=10)
        if self._reader is not None:
            self._reader.join(timeout=10)

    def _read(self) -> None:
        assert self._process is not None and self._process.stdout is not None
        for line in self._process.stdout:
            if line.strip() == "ready":
                self._ready.set()
                continue
            start, end = (float(x) for x in line.split())
            with self._lock:
                self.stalls.append((start, end))

    def stalled(self, start: float, end: float) -> float:
        """Seconds within ``[start, end]`` during which the machine stalled."""
        with self._lock:
            return sum(max(0.0, min(end, b) - max(start, a)) for a, b in self.stalls)
