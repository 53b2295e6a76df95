"""Rate-limit Cyclone's "malformed packet" lines, so garbage on a socket cannot flood the log.

Cyclone DDS writes one warning line (a hex dump, ~170 bytes) to standard error for every
malformed datagram it receives: 18,000 garbage packets gave 3.1 MB of log. The Python
binding offers no log callback (``dds_set_log_sink`` is not exported by the 11.x library)
and the verbosity setting could only hide every warning, so the filter sits on the
process's standard error instead: file descriptor 2 becomes a pipe read by one thread,
which passes every line through unchanged except Cyclone's malformed-packet lines, of which
at most :data:`LIMIT` per :data:`WINDOW` seconds are shown; then one line says how many
more were not shown. At exit the pipe is drained and the real standard error restored, so
nothing written before (a traceback, say) is lost. ``BLACKBOX_CYCLONE_LOG=raw`` turns the
filter off.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import sys
import threading
import time

LIMIT = 5
WINDOW = 10.0
MARKER = b"malformed packet"
_installed: _StderrFilter | None = None
_lock = threading.Lock()


class _StderrFilter:
    def __init__(self) -> None:
        self.original = os.dup(2)
        read_fd, write_fd = os.pipe()
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        os.dup2(write_fd, 2)
        os.close(write_fd)
        self.read_fd = read_fd
        self.shown = 0
        self.suppressed = 0
        self.total_suppressed = 0
        self.window_start = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="blackbox-cyclone-log",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        pending = b""
        while True:
            try:
                chunk = os.read(self.read_fd, 65536)
            except OSError:
                break
            if not chunk:
                break
            pending += chunk
            *lines, pending = pending.split(b"\n")
            out = b"".join(self.filter(line) for line in lines)
            self._write(out)
        self._write(pending + self.flush_summary())

    def filter(self, line: bytes) -> bytes:
        """The line to write for ``line`` (``b""`` when it is held back)."""
        now = time.monotonic()
        head = b""
        if now - self.window_start >= WINDOW:
            head = self.flush_summary()
            self.window_start, self.shown = now, 0
        if MARKER not in line:
            return head + line + b"\n"
        if self.shown < LIMIT:
            self.shown += 1
            return head + line + b"\n"
        self.suppressed += 1
        self.total_suppressed += 1
        return head

    def flush_summary(self) -> bytes:
        if not self.suppressed:
            return b""
        text = (f"blackbox: {self.suppressed} more malformed DDS packets in the last "
                f"{WINDOW:g} s not shown (at most {LIMIT} per {WINDOW:g} s)\n")
        self.suppressed = 0
        return text.encode()

    def _write(self, data: bytes) -> None:
        while data:
            try:
                n = os.write(self.original, data)
            except OSError:
                return
            data = data[n:]

    def stop(self) -> None:
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        os.dup2(self.original, 2)  # the pipe's last writer goes: the thread sees its end
        self._thread.join(timeout=2.0)


def limit_malformed_packet_logging() -> None:
    """Install the filter once per process (called when the first DDS bus opens)."""
    global _installed
    if os.environ.get("BLACKBOX_CYCLONE_LOG") == "raw":
        return
    with _lock:
        if _installed is None:
            try:
                _installed = _StderrFilter()
            except OSError:
                return
            atexit.register(_installed.stop)


def suppressed() -> int:
    """Malformed-packet lines held back so far in this process."""
    return _installed.total_suppressed if _installed is not None else 0
