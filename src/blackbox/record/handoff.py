"""The bounded hand-over between the pipeline thread and the recorder's writer thread.

The pipeline appends batches of rows (and finished snapshot captures); the writer takes
them. What is handed over but not yet committed is counted in ``pending``; that count is
what is bounded, with one of two policies (see docs/recorder.md, "Under load"):

``block`` (a simulated clock)
    The pipeline waits until the writer has committed what waits, so a run as fast as
    possible never outruns durable storage. While the disk fails it does not wait
    (it could wait forever) and falls back to ``drop``.
``drop`` (real time: the robot does not wait)
    Over the limit, incoming periodic samples are dropped first, then state changes and
    diagnoses once ``pending`` exceeds the limit by a quarter; failures, the black box's
    own events, snapshots and configurations are always kept. Every dropped record is
    counted by kind, and the counts are written into the log itself
    (``blackbox_event`` ``records_dropped``).

Every batch carries the wall-clock time it was handed over at (stamped under the lock).
:meth:`Handoff.take` returns, with the batches, the wall-clock time it took them at, under
the same lock: every batch handed over before that time is among them. The writer stores
that time as the log's progress marker (``meta`` key ``progress``, ``wall``) in the same
transaction as the rows, so after a crash the log holds everything the pipeline handed
over before ``progress.wall``; that is how the crash test measures how far the durable
record lags the pipeline.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from blackbox.model import Observation
from blackbox.record.snapshot import Capture
from blackbox.record.store import KINDS, Channel

#: A row on its way to the store. The pipeline thread queues logged observations as the
#: observation itself, which is immutable; the writer thread encodes it.
Pending = tuple[float, str, Channel | None, int | None, "dict[str, Any] | str | Observation"]

#: Kinds that are never dropped for lack of room (retention priority 20 and above).
ALWAYS_KEPT = frozenset(k for k, v in KINDS.items() if v >= KINDS["snapshot"])
_CHANGES = frozenset(k for k, v in KINDS.items() if 0 < v < KINDS["snapshot"])


class Handoff:
    """The queue between the threads, its bound and its policy."""

    def __init__(self, limit: int, policy: str, block_above: int) -> None:
        self.limit = limit
        self.policy = policy
        self.block_above = max(1, min(block_above, limit))
        self.items: deque[tuple[float, list[Pending]] | Capture] = deque()
        self.pending = 0
        self.dropped: dict[str, int] = {}
        self.failing = False
        self.closed = False
        self.on_full: Callable[[], None] | None = None
        self._cond = threading.Condition()

    @property
    def dropped_total(self) -> int:
        with self._cond:
            return sum(self.dropped.values())

    def dropped_by_kind(self) -> dict[str, int]:
        with self._cond:
            return dict(self.dropped)

    def put(self, rows: list[Pending], force: bool = False) -> bool:
        """Hand ``rows`` over; returns whether the writer should be woken now."""
        if not force:
            rows = self._admit(rows)
            if not rows:
                return False
        with self._cond:
            self.pending += len(rows)
            self.items.append((time.time(), rows))
            return self.pending >= self.block_above

    def put_capture(self, capture: Capture) -> None:
        with self._cond:
            self.items.append(capture)

    def _admit(self, rows: list[Pending]) -> list[Pending]:
        if self.pending + len(rows) <= (self.block_above if self.policy == "block"
                                        else self.limit):
            return rows
        if self.policy == "block" and not self.failing and not self.closed:
            self._wait_for_room(len(rows))
            if self.pending + len(rows) <= self.limit:
                return rows
        kept = [r for r in rows if r[1] != "sample"]
        if self.pending + len(kept) > self.limit * 5 // 4:
            kept = [r for r in kept if r[1] not in _CHANGES]
        if len(kept) != len(rows):
            self._count_dropped(rows, kept)
        return kept

    def _wait_for_room(self, n: int) -> None:
        if self.on_full is not None:
            self.on_full()  # wake the writer: it may be sleeping until its next interval
        with self._cond:
            self._cond.wait_for(lambda: self.pending + n <= self.block_above or self.pending == 0
                                or self.failing or self.closed, timeout=30.0)

    def _count_dropped(self, rows: list[Pending], kept: list[Pending]) -> None:
        kept_ids = {id(r) for r in kept}
        with self._cond:
            for r in rows:
                if id(r) not in kept_ids:
                    self.dropped[r[1]] = self.dropped.get(r[1], 0) + 1

    def count_dropped(self, kind: str, n: int) -> None:
        """The writer dropped ``n`` rows of ``kind`` from its backlog (disk failing)."""
        with self._cond:
            self.dropped[kind] = self.dropped.get(kind, 0) + n
            self.pending = max(0, self.pending - n)
            self._cond.notify_all()

    def take(self) -> tuple[list[tuple[float, list[Pending]] | Capture], float]:
        """Everything handed over so far, and the wall-clock time it was taken at: every
        batch handed over before that time is in the list (writer thread)."""
        with self._cond:
            items = list(self.items)
            self.items.clear()
            return items, time.time()

    def committed(self, n: int) -> None:
        """``n`` rows are durable now: make room for the pipeline."""
        with self._cond:
            self.pending = max(0, self.pending - n)
            self._cond.notify_all()

    def set_failing(self, failing: bool) -> None:
        with self._cond:
            self.failing = failing
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()
