"""The recorder's writer thread: commits the health log, keeps it in budget, survives the disk.

It takes what the pipeline handed over (:class:`~blackbox.record.handoff.Handoff`),
encodes it and commits it every ``commit_interval`` seconds in one transaction (so a crash
loses at most that interval), or as soon as ``commit_rows`` rows wait. Every scheduled
commit happens, even with nothing new to write: it moves the progress marker ("the log
holds everything handed over before this wall time"), so a pipeline with nothing to hand
over is not mistaken for a writer falling behind. One transaction (one fsync) per commit:
new snapshot files are noted in the log's manifest in the same transaction as the rows,
then handed to their own thread (:class:`~blackbox.record.capture_writer.CaptureWriter`);
retention runs after the commit.

When writing fails (disk full, I/O error, corrupt file) the rows stay in a bounded
backlog, the failure is reported as a self-event, and the store is reopened every
``retry_interval`` seconds until the disk works again. A log of ours that turns out
corrupt is moved aside and a new one started; any other file is never touched.
"""

from __future__ import annotations

import contextlib
import operator
import os
import sqlite3
import threading
import time as _time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from blackbox.model import BlackBoxEvent, Code
from blackbox.record.capture_writer import PART, CaptureWriter
from blackbox.record.handoff import ALWAYS_KEPT, Handoff
from blackbox.record.logfile import classify, set_aside
from blackbox.record.retention import Retention, enforce_directory
from blackbox.record.settings import RecorderSettings
from blackbox.record.snapshot import Capture
from blackbox.record.store import Row, RowTuple, StorageError, Store, StoreCorrupt, dumps

COMPONENT = "blackbox/recorder"
_TIME = operator.itemgetter(0)
OWN = (COMPONENT, "event", "{}")


@dataclass(frozen=True, slots=True)
class ConfigVersion:
    """A configuration stored in the log: imported ones are handed to ``on_config``."""

    version: int
    time: float
    text: str
    source: str
    entry_id: int


def own_event(time: float, payload: dict[str, Any], code: Code | None = None) -> Row:
    """A row of the recorder's own ``blackbox_event`` channel."""
    return Row(time, "blackbox_event", OWN, None if code is None else int(code), payload)


class LogWriter:
    """The thread that owns the store. Shared with the pipeline thread: ``handoff``,
    ``events``, ``configs`` and the counters; everything else is this thread's."""

    def __init__(self, settings: RecorderSettings, robot_id: str, handoff: Handoff,
                 clock: Callable[[], float], snapshot_format: str | None) -> None:
        self.settings = settings
        self.path = settings.path
        self.robot_id = robot_id
        self.handoff = handoff
        self.clock = clock
        self.retention = Retention(settings.budget_bytes - settings.snapshot_budget)
        self.snapshot_dir = settings.snapshot_dir
        self.events: deque[BlackBoxEvent] = deque()
        self.configs: deque[ConfigVersion] = deque()
        self.written = 0
        self.used_bytes = 0
        self.error: str | None = None
        self._error_since: float | None = None
        self._backlog: list[RowTuple] = []
        self._backlog_wall = 0.0  # the newest hand-over in the backlog
        self._complete_wall = 0.0  # the backlog holds every hand-over before this time
        self._newest_time: float | None = None  # of the rows written so far
        self._handed = 0  # rows of the backlog that came through the hand-over
        self._dropped_logged = 0
        self._store: Store | None = None
        self._next_retry = 0.0
        self._seen_config_id = 0
        self._unregistered: list[Capture] = []
        self._stop = threading.Event()
        self.wake = threading.Event()
        self.captures: CaptureWriter | None = None
        if snapshot_format is not None and settings.snapshot is not None:
            self.captures = CaptureWriter(self.snapshot_dir, snapshot_format, self._snapshot_done,
                                          retries=settings.snapshot.retries,
                                          retry_interval=settings.retry_interval)
        self._open_store()
        self._thread = threading.Thread(target=self._run, name="blackbox-recorder", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float) -> None:
        """Commit everything handed over, finish the snapshots, close the store."""
        self._stop.set()
        self.wake.set()
        self._thread.join(timeout)

    @property
    def backlog(self) -> int:
        return len(self._backlog)

    # ---- the loop -------------------------------------------------------------------------

    def _run(self) -> None:
        commit_interval = self.settings.commit_interval
        next_retention = 0.0
        # Commits start every commit_interval, however long the previous one took, so a
        # crash loses at most that interval (or the one commit that runs late under load).
        next_commit = _time.monotonic() + commit_interval
        while True:
            self.wake.wait(max(0.0, next_commit - _time.monotonic()))
            self.wake.clear()
            stopping = self._stop.is_set()
            now = _time.monotonic()
            due = now >= next_commit  # else woken early (commit_rows, a snapshot row)
            if due:
                next_commit = max(next_commit + commit_interval, now)
            try:
                self._write_pending(due or stopping)
                now = _time.monotonic()
                if self._store is not None and (now >= next_retention or stopping):
                    next_retention = now + self.settings.retention_interval
                    self._enforce_budget()
            except Exception as exc:  # the writer thread must never die silently
                self._fail(f"recorder error: {type(exc).__name__}: {exc}")
            if stopping and not self.handoff.items:
                if self.captures is not None:
                    self.captures.close(timeout=20.0)
                    with contextlib.suppress(Exception):
                        self._write_pending(True)  # the snapshot rows of the last captures
                        if self._store is not None:
                            self._enforce_budget()
                            self._write_pending(True)
                break
        if self._store is not None:
            with contextlib.suppress(Exception):
                self._store.close()
            self._store = None

    def _take(self) -> list[Capture]:
        captures: list[Capture] = []
        backlog = self._backlog
        items, self._complete_wall = self.handoff.take()
        for item in items:
            if isinstance(item, Capture):
                captures.append(item)
                continue
            wall, rows = item
            self._backlog_wall = max(self._backlog_wall, wall)
            self._handed += len(rows)
            backlog += rows  # logged observations stay objects: the store frames them
        self._trim_backlog()
        return captures

    def _trim_backlog(self) -> None:
        """While the disk fails the backlog is bounded like the hand-over: samples go
        first, then changes; failures, events, snapshots and configurations stay (up to
        four times the limit, the oldest going first beyond that)."""
        limit = self.settings.queue_limit
        backlog = self._backlog
        if len(backlog) <= limit * 5 // 4:
            return
        kept = [r for r in backlog if r[1] != "sample"]
        if len(kept) > limit * 5 // 4:
            kept = [r for r in kept if r[1] in ALWAYS_KEPT]
        if len(kept) > limit * 4:
            kept = kept[-limit * 4:]
        kept_ids = {id(r) for r in kept}
        by_kind: dict[str, int] = {}
        for r in backlog:
            if id(r) not in kept_ids:
                by_kind[r[1]] = by_kind.get(r[1], 0) + 1
        for kind, n in by_kind.items():
            self.handoff.count_dropped(kind, n)
        self._handed = max(0, self._handed - sum(by_kind.values()))
        self._backlog = kept

    def _write_pending(self, due: bool) -> None:
        """Commit what waits; with ``due`` (the commit interval is up) also when only the
        progress marker moves."""
        captures = self._unregistered + self._take()
        self._unregistered = []
        store = self._store
        if store is None:
            if _time.monotonic() < self._next_retry or not self._open_store():
                self._unregistered = captures
                return
            store = self._store
            assert store is not None
        if due or captures or self._backlog or \
                self.handoff.dropped_total != self._dropped_logged:
            if not self._commit(store, captures):
                self._unregistered = captures
                return
            if captures:
                assert self.captures is not None
                for capture in captures:
                    self.captures.put(capture)
        if self._store is not None:
            self._poll_imports(self._store)

    def _commit(self, store: Store, captures: list[Capture]) -> bool:
        """One transaction: the rows, the progress marker and the new snapshot files in
        the manifest (noted before they exist, so retention may delete them)."""
        dropped = self.handoff.dropped_by_kind()
        total = sum(dropped.values())
        extra: list[RowTuple] = []
        if total != self._dropped_logged:
            extra.append(own_event(self.clock(), {"event": "records_dropped", "total": total,
                                                  "by_kind": dropped}))
        rows = self._backlog + extra
        self._newest_time = max(map(_TIME, self._backlog), default=self._newest_time)
        progress = dumps({"wall": self._complete_wall, "handed": self._backlog_wall,
                          "pid": os.getpid(), "time": self._newest_time})
        created = _time.time()
        try:
            store.append(rows, meta={"progress": progress},
                         snapshots=[(c.name, created) for c in captures], want_ids=False)
        except (sqlite3.Error, OSError) as exc:
            self._storage_trouble(exc)
            return False
        self.written += len(rows)
        self.handoff.committed(self._handed)
        self._handed = 0
        self._dropped_logged = total
        self._backlog = []
        if self.error is not None:
            self._recovered()
        return True

    def _snapshot_done(self, row: Row, error: str | None) -> None:
        # Called on the snapshot thread: rows go through the hand-over like any other.
        if error is not None:
            self.events.append(BlackBoxEvent(self.clock(), "snapshot_error", error, COMPONENT))
        self.handoff.put([row], force=True)
        self.wake.set()

    # ---- failure and recovery -------------------------------------------------------------

    def _storage_trouble(self, exc: BaseException) -> None:
        text = str(exc)
        corrupt = isinstance(exc, sqlite3.DatabaseError) and \
            not isinstance(exc, sqlite3.OperationalError)
        if corrupt or "malformed" in text or "not a database" in text:
            store, self._store = self._store, None
            if store is not None:
                with contextlib.suppress(Exception):
                    store.close()
            self._set_aside_and_reopen(text)
            return
        self._fail(f"cannot write health log {self.path}: {text}")

    def _fail(self, message: str) -> None:
        if self.error is None:
            self._error_since = self.clock()
            self.events.append(BlackBoxEvent(self._error_since, "storage_error", message,
                                             COMPONENT))
        self.error = message
        self.handoff.set_failing(True)
        self._next_retry = _time.monotonic() + self.settings.retry_interval
        if self._store is not None and ("full" in message or "I/O" in message):
            # Drop the connection: a fresh one re-reads the file after space returns.
            with contextlib.suppress(Exception):
                self._store.close()
            self._store = None

    def _recovered(self) -> None:
        message = (f"writing health log {self.path} again after: {self.error}; "
                   f"{self.handoff.dropped_total} records dropped so far")
        now = self.clock()
        self.events.append(BlackBoxEvent(now, "storage_resumed", message, COMPONENT))
        rows = [own_event(self._error_since or now, {"event": "storage_error",
                                                      "message": self.error},
                          Code.GENERAL_ERROR),
                own_event(now, {"event": "storage_resumed",
                                "dropped": self.handoff.dropped_total}, Code.GENERAL_OK)]
        self.error = None
        self._error_since = None
        self.handoff.set_failing(False)
        store = self._store
        if store is not None:
            try:
                store.append(rows)
                self.written += len(rows)
            except (sqlite3.Error, OSError) as exc:
                self._storage_trouble(exc)

    def _open_store(self) -> bool:
        try:
            store = Store.open(self.path, durability=self.settings.durability)
        except StoreCorrupt as exc:
            return self._set_aside_and_reopen(str(exc))
        except StorageError as exc:
            self._fail(str(exc))
            return False
        self._attach(store)
        return True

    def _set_aside_and_reopen(self, reason: str) -> bool:
        if classify(self.path) == "foreign":  # never ours to move: stay failing instead
            self._fail(f"health log {self.path} was replaced by a file that is not a health "
                       f"log ({reason}); it is left untouched")
            return False
        try:
            aside = set_aside(self.path)
        except OSError as exc:
            self._fail(f"health log {self.path} is corrupt ({reason}) and cannot be moved "
                       f"aside: {exc}")
            return False
        message = (f"health log {self.path} was corrupt ({reason}); moved to {aside.name} "
                   "and started a new one")
        now = self.clock()
        self.events.append(BlackBoxEvent(now, "storage_corrupt", message, COMPONENT))
        try:
            store = Store.open(self.path, durability=self.settings.durability)
        except StorageError as exc:  # never a loop: stay failing and retry later
            self._fail(f"{message}, but the new one failed too: {exc}")
            return False
        self._attach(store)
        self._backlog.insert(0, own_event(now, {"event": "storage_corrupt", "message": message,
                                                "set_aside": aside.name}, Code.GENERAL_ERROR))
        return True

    def _attach(self, store: Store) -> None:
        self._store = store
        with contextlib.suppress(sqlite3.Error):
            store.set_meta("robot_id", self.robot_id)
        latest = None
        with contextlib.suppress(sqlite3.Error):
            latest = store.latest("config")
        self._seen_config_id = latest.id if latest else 0
        with contextlib.suppress(sqlite3.Error, OSError):
            self.used_bytes = store.used_bytes()
        with contextlib.suppress(sqlite3.Error, OSError):
            for name in store.snapshot_files():  # half-written files of a killed run
                Path(self.snapshot_dir, name + PART).unlink(missing_ok=True)

    def _poll_imports(self, store: Store) -> None:
        """Hand configurations imported by ``blackbox log import`` to the pipeline."""
        try:
            new = list(store.query(kinds=["config"], after_id=self._seen_config_id))
        except sqlite3.Error:
            return
        for entry in sorted(new, key=lambda e: e.id):
            self._seen_config_id = max(self._seen_config_id, entry.id)
            version = int(entry.payload.get("version") or 0)
            if entry.payload.get("source") == "import":
                self.configs.append(ConfigVersion(version, entry.time,
                                                  str(entry.payload.get("text", "")),
                                                  "import", entry.id))

    # ---- the disk budget ------------------------------------------------------------------

    def _enforce_budget(self) -> None:
        store = self._store
        assert store is not None
        try:
            report = self.retention.enforce(store)
            self.used_bytes = report.after_bytes
            if report.acted:
                store.append([own_event(self.clock(), {
                    "event": "retention", "thinned": report.thinned, "dropped": report.dropped,
                    "before_bytes": report.before_bytes, "after_bytes": report.after_bytes})])
            if self.captures is not None and self.snapshot_dir.exists():
                self._enforce_snapshots(store)
        except (sqlite3.Error, OSError) as exc:
            self._storage_trouble(exc)

    def _enforce_snapshots(self, store: Store) -> None:
        removed = enforce_directory(self.snapshot_dir, self.settings.snapshot_budget,
                                    store.snapshot_files())
        if removed:
            store.forget_snapshots(removed)
            self._backlog.append(own_event(self.clock(), {"event": "snapshots_deleted",
                                                          "files": removed}))

