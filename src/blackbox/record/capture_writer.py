"""Writes snapshot files on a thread of their own, so they never delay the log's commits.

A capture can hold tens of megabytes; encoding it into a bag or an MCAP file takes long
enough that committing the health log's rows behind it would break the recorder's
"a crash loses at most one commit interval" promise. So the writer thread only notes the
file in the log's manifest and hands the capture over; this thread writes it to
``NAME.part``, renames it to ``NAME`` once complete (a reader never sees half a file) and
reports the result as a ``snapshot`` row. A failed write (a full disk) removes the part
file, so no empty or truncated file is left, and is retried ``retries`` times,
``retry_interval`` apart, before the snapshot is reported lost.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from blackbox.record.snapshot import WRITERS, Capture
from blackbox.record.store import Row

PART = ".part"


class CaptureWriter:
    """One thread writing snapshot captures into ``directory``.

    ``report(row, error)`` is called on this thread with the ``snapshot`` row of every
    capture, written or given up, and an error text or ``None``.
    """

    def __init__(self, directory: Path, fmt: str,
                 report: Callable[[Row, str | None], None], *, retries: int = 3,
                 retry_interval: float = 2.0) -> None:
        self.directory = directory
        self.fmt = fmt
        self.report = report
        self.retries = retries
        self.retry_interval = retry_interval
        self.written = 0
        self._queue: deque[tuple[Capture, int, float]] = deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="blackbox-snapshots",
                                        daemon=True)
        self._thread.start()

    def put(self, capture: Capture) -> None:
        self._queue.append((capture, 0, 0.0))
        self._wake.set()

    def close(self, timeout: float) -> None:
        """Write what is queued (one attempt each, no more waiting for retries) and stop."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout)

    @property
    def busy(self) -> bool:
        return bool(self._queue)

    def _run(self) -> None:
        while True:
            self._wake.wait(0.5)
            self._wake.clear()
            stopping = self._stop.is_set()
            for _ in range(len(self._queue)):
                capture, attempt, not_before = self._queue.popleft()
                if not stopping and time.monotonic() < not_before:
                    self._queue.append((capture, attempt, not_before))
                    continue
                self._attempt(capture, attempt, final=stopping)
            if stopping:
                return

    def _attempt(self, capture: Capture, attempt: int, final: bool) -> None:
        path = self.directory / capture.name
        payload: dict[str, Any] = {"file": capture.name, "format": self.fmt,
                                   "trigger": capture.trigger, "end": capture.end,
                                   "dropped_messages": capture.dropped}
        try:
            result = self._write(capture, path)
        except Exception as exc:
            if attempt < self.retries and not final:
                self._queue.append((capture, attempt + 1,
                                    time.monotonic() + self.retry_interval))
                return
            payload["error"] = f"{type(exc).__name__}: {exc}"
            payload["attempts"] = attempt + 1
            self.report(Row(capture.trigger, "snapshot", None, None, payload),
                        f"cannot write snapshot {path}: {exc}")
            return
        self.written += 1
        payload.update(messages=result.messages, bytes=result.bytes,
                       topics=list(result.topics), skipped_topics=list(result.skipped_topics))
        if attempt:
            payload["attempts"] = attempt + 1
        self.report(Row(capture.trigger, "snapshot", None, None, payload), None)

    def _write(self, capture: Capture, path: Path) -> Any:
        part = path.with_name(path.name + PART)
        try:
            result = WRITERS[self.fmt](capture.messages, capture.schemas, part)
            part.replace(path)
        except BaseException:
            with contextlib.suppress(OSError):
                part.unlink()
            raise
        return result
