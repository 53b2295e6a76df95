"""The black box recorder: a sink that keeps the health log, whatever happens to the disk.

The pipeline thread only decides what to keep (policy), appends the kept observations
to an in-memory queue and feeds the snapshot ring buffer: nothing on that path touches
the disk or encodes anything, so a slow, full or broken disk never delays observation.
A background writer thread encodes the queue and commits it every ``commit_interval``
seconds in one transaction (so a crash loses at most that interval), or as soon as
``commit_rows`` rows are waiting, so that under heavy load SQLite writes one batch while
the pipeline thread queues the next. It also enforces the disk budget and writes
snapshot files.

When writing fails (disk full, I/O error, corrupt file) the recorder keeps accepting
records into a bounded backlog, counts what it must drop, reports itself faulty through
:meth:`Recorder.health` and ``on_self_event`` and retries until the disk works again.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sqlite3
import threading
import time as _time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal, cast

from blackbox.config.node import ConfigNode
from blackbox.events import MessageArrival, TopicSchema
from blackbox.model import BlackBoxEvent, Code, Diagnosis, Observation, Resource
from blackbox.record.policy import (
    FaultBoost,
    LoggingPolicy,
    PolicyRule,
    PolicyTracker,
    observation_payload,
)
from blackbox.record.retention import Retention, enforce_directory
from blackbox.record.snapshot import (
    SUFFIXES,
    WRITERS,
    Capture,
    RingBuffer,
    SnapshotConfig,
)
from blackbox.record.store import (
    Channel,
    Row,
    RowTuple,
    StorageError,
    Store,
    StoreCorrupt,
    dumps,
)
from blackbox.sinks import SinkBase

COMPONENT = "blackbox/recorder"
RESOURCE = Resource(node="/blackbox/recorder")
DEFAULT_BUDGET = 1024**3

#: A row on its way to the store. The pipeline thread queues logged observations as the
#: observation itself, which is immutable; the writer thread encodes it (see _encoded).
Pending = tuple[float, str, Channel | None, int | None, "dict[str, Any] | str | Observation"]


@dataclass(frozen=True, slots=True)
class ConfigVersion:
    """A configuration stored in the log: imported ones are handed to ``on_config``."""

    version: int
    time: float
    text: str
    source: str
    entry_id: int


def set_aside(path: Path, now: float | None = None) -> Path:
    """Rename a broken log (and its WAL files) out of the way; returns the new name."""
    stamp = datetime.fromtimestamp(now if now is not None else _time.time(), UTC)
    aside = path.with_name(f"{path.name}.corrupt-{stamp:%Y%m%dT%H%M%SZ}")
    n = 1
    while aside.exists():
        aside = path.with_name(f"{path.name}.corrupt-{stamp:%Y%m%dT%H%M%SZ}-{n}")
        n += 1
    path.rename(aside)
    for suffix in ("-wal", "-shm"):
        extra = Path(f"{path}{suffix}")
        if extra.exists():
            extra.rename(Path(f"{aside}{suffix}"))
    return aside


def config_entry_row(now: float, text: str, source: str, **extra: Any) -> Row:
    """A configuration version; ``version`` is assigned when it is written."""
    payload = {"version": None, "source": source,
               "sha256": hashlib.sha256(text.encode()).hexdigest(), "text": text, **extra}
    return Row(now, "config", None, None, payload)


class Recorder(SinkBase):
    """Sink writing the health log at ``path`` and snapshots beside it.

    Callbacks ``on_self_event`` (the recorder's own failures and recoveries) and
    ``on_config`` (configurations imported while running) are called on the pipeline
    thread, from inside the next ``on_*`` call, never from the writer thread.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        robot_id: str,
        policy: LoggingPolicy | None = None,
        snapshot: SnapshotConfig | None = None,
        budget_bytes: int = DEFAULT_BUDGET,
        commit_interval: float = 1.0,
        commit_rows: int = 10_000,
        schema_lookup: Callable[[str], TopicSchema | None] | None = None,
        snapshot_format: Literal["ros1", "mcap"] = "ros1",
        snapshot_dir: str | Path | None = None,
        snapshot_share: float = 0.25,
        snapshot_cooldown: float = 60.0,
        durability: Literal["full", "normal"] = "full",
        queue_limit: int = 200_000,
        retention_interval: float = 10.0,
        retry_interval: float = 2.0,
        clock: Callable[[], float] = _time.time,
        on_self_event: Callable[[BlackBoxEvent], None] | None = None,
        on_config: Callable[[ConfigVersion], None] | None = None,
    ) -> None:
        if snapshot_format not in WRITERS:
            raise ValueError(f"snapshot_format must be one of {', '.join(WRITERS)}")
        self.path = Path(path)
        self.robot_id = robot_id
        self.policy = policy or LoggingPolicy()
        self.commit_interval = commit_interval
        self.commit_rows = commit_rows
        self.schema_lookup = schema_lookup
        self.snapshot_format = snapshot_format
        self.snapshot_dir = Path(snapshot_dir) if snapshot_dir else \
            self.path.with_name(self.path.name + ".snapshots")
        self.snapshot_cooldown = snapshot_cooldown
        self.durability = durability
        self.queue_limit = queue_limit
        self.retry_interval = retry_interval
        self.retention_interval = retention_interval
        self.clock = clock
        self.on_self_event = on_self_event
        self.on_config = on_config
        self._snapshot_budget = int(budget_bytes * snapshot_share) if snapshot else 0
        self.retention = Retention(budget_bytes - self._snapshot_budget)
        self.ring = RingBuffer(snapshot) if snapshot else None
        self.wants_messages = self.ring is not None
        self._tracker = PolicyTracker(self.policy)
        self._last_capture_end = float("-inf")
        self._last_diagnosis: tuple[frozenset[str], ...] | None = None
        self._last_failure: frozenset[str] = frozenset()

        # Shared between the threads: deque appends and pops are atomic.
        self._queue: deque[list[Pending] | Capture] = deque()
        self._queued_rows = 0
        self._count_lock = threading.Lock()
        self._self_events: deque[BlackBoxEvent] = deque()
        self._configs: deque[ConfigVersion] = deque()
        self.dropped = 0
        self.written = 0
        self.snapshots_written = 0
        self.used_bytes = 0
        self._error: str | None = None
        self._error_since: float | None = None

        # Writer side only.
        self._backlog: list[RowTuple] = []
        self._store: Store | None = None
        self._next_retry = 0.0
        self._seen_config_id = 0
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._open_store(initial=True)
        self._queue_rows([Row(self.clock(), "blackbox_event", (COMPONENT, "event", "{}"), None,
                              {"event": "start", "robot_id": robot_id, "pid": os.getpid()})])
        self._thread = threading.Thread(target=self._run, name="blackbox-recorder", daemon=True)
        self._thread.start()

    # ---- configuration ----------------------------------------------------------------------

    @classmethod
    def from_config(cls, section: ConfigNode | None, robot_id: str, base_dir: str | Path,
                    **kwargs: Any) -> Recorder:
        """A recorder from a native ``recorder:`` section (see docs/recorder.md)."""
        return cls(**recorder_options(section, Path(base_dir)), robot_id=robot_id, **kwargs)

    def record_config(self, text: str, source: str = "startup", **extra: Any) -> None:
        """Store a configuration version (the one the black box starts with, say)."""
        self._queue_rows([config_entry_row(self.clock(), text, source, **extra)])

    # ---- sink -------------------------------------------------------------------------------

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        rows: list[Pending] = []
        decide = self._tracker.decide
        for obs in observations:
            d = decide(obs)
            if d is None:
                continue
            if d.snapshot and self.ring is not None:
                payload = observation_payload(obs, True)
                path = self._trigger_snapshot(obs.time, f"{obs.observer} {obs.resource.label()}")
                if path:
                    payload["snapshot"] = path
                rows.append((obs.time, d.kind, d.channel, int(obs.code), payload))
            else:
                rows.append((obs.time, d.kind, d.channel, obs.code, obs))
        if rows:
            self._queue_rows(rows)
        self._after_call(now)

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        cands = diagnosis.candidates
        if cands != self._last_diagnosis:
            self._last_diagnosis = cands
            failed = [{"observer": o.observer, "resource": o.resource.label(), "code": int(o.code)}
                      for o in diagnosis.failed]
            rows: list[Pending] = [Row(diagnosis.time, "diagnosis", None, None,
                        {"candidates": [sorted(c) for c in cands], "failed": failed,
                         "explanation": diagnosis.explanation, "complete": diagnosis.complete,
                         "engine": diagnosis.engine, "agreement": diagnosis.agreement})]
            best = cands[0] if cands else frozenset()
            if best != self._last_failure:
                payload: dict[str, Any] = {"components": sorted(best)}
                if best:
                    payload["category"] = "detection"
                    payload["explanation"] = diagnosis.explanation
                    if self.ring is not None:
                        path = self._trigger_snapshot(diagnosis.time, "failure " + ",".join(
                            sorted(best)))
                        payload["snapshot"] = path
                else:
                    payload["category"] = "rectification"
                    payload["components"] = sorted(self._last_failure)
                self._last_failure = best
                rows.append(Row(diagnosis.time, "failure", None, None, payload))
            self._queue_rows(rows)
        self._after_call(diagnosis.time)

    def on_event(self, event: BlackBoxEvent) -> None:
        if event.component == COMPONENT:
            return  # the recorder logs its own events itself, once it can write again
        self._queue_rows([Row(event.time, "blackbox_event", (event.component, "event", "{}"),
                              None, {"event": event.kind, "message": event.message})])
        self._after_call(event.time)

    def on_message(self, msg: MessageArrival) -> None:
        ring = self.ring
        if ring is not None:
            ring.offer(msg)

    def close(self, timeout: float = 30.0) -> None:
        """Finish open snapshots, write everything queued and close the log."""
        if self._stop.is_set():
            return
        if self.ring is not None:
            for capture in self.ring.flush():
                self._hand_over(capture)
        self._queue_rows([Row(self.clock(), "blackbox_event", (COMPONENT, "event", "{}"), None,
                              {"event": "stop", "dropped": self.dropped})], force=True)
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout)
        self._deliver()

    # ---- health -----------------------------------------------------------------------------

    def health(self) -> Observation:
        """The recorder's own observation: ``GENERAL_ERROR`` while it cannot write."""
        values = {"queued_rows": float(self._queued_rows + len(self._backlog)),
                  "dropped": float(self.dropped), "written": float(self.written),
                  "used_bytes": float(self.used_bytes)}
        error = self._error
        if error:
            return Observation(self.clock(), "recorder", RESOURCE, Code.GENERAL_ERROR,
                               values=values, message=error)
        return Observation(self.clock(), "recorder", RESOURCE, Code.GENERAL_OK, values=values)

    @property
    def failing(self) -> bool:
        return self._error is not None

    # ---- pipeline-thread helpers --------------------------------------------------------------

    def _queue_rows(self, rows: list[Pending], force: bool = False) -> None:
        if not force and self._queued_rows + len(rows) > self.queue_limit:
            kept = [r for r in rows if r[1] != "sample"]
            self.dropped += len(rows) - len(kept)
            rows = kept
            if self._queued_rows + len(rows) > self.queue_limit * 5 // 4:
                self.dropped += len(rows)
                return
            if not rows:
                return
        with self._count_lock:
            self._queued_rows += len(rows)
        self._queue.append(rows)
        if self._queued_rows >= self.commit_rows and self._error is None \
                and not self._wake.is_set():
            self._wake.set()  # while the disk fails, retries stay one per interval

    def _trigger_snapshot(self, time: float, reason: str) -> str | None:
        ring = self.ring
        assert ring is not None
        running = ring.active(time)
        if running is not None:
            return running.name
        if time < self._last_capture_end + self.snapshot_cooldown:
            return None
        stamp = datetime.fromtimestamp(max(time, 0.0), UTC)
        name = f"{self.robot_id}-{stamp:%Y%m%dT%H%M%S}-{int(time * 1000) % 1000:03d}"
        name += SUFFIXES[self.snapshot_format]
        capture = ring.trigger(time, name)
        self._last_capture_end = capture.end
        return name

    def _after_call(self, now: float) -> None:
        ring = self.ring
        if ring is not None:
            for capture in ring.complete(now):
                self._hand_over(capture)
        if self._self_events or self._configs:
            self._deliver()

    def _hand_over(self, capture: Capture) -> None:
        lookup = self.schema_lookup
        for topic in {h.topic for h in capture.messages}:
            capture.schemas[topic] = lookup(topic) if lookup else None
        self._queue.append(capture)

    def _deliver(self) -> None:
        while self._self_events:
            event = self._self_events.popleft()
            if self.on_self_event is not None:
                self.on_self_event(event)
        while self._configs:
            version = self._configs.popleft()
            if self.on_config is None:
                continue
            try:
                self.on_config(version)
            except Exception as exc:
                self._queue_rows([Row(self.clock(), "blackbox_event",
                                      (COMPONENT, "event", "{}"), None,
                                      {"event": "config_rejected", "version": version.version,
                                       "message": str(exc)})])
            else:
                self._queue_rows([Row(self.clock(), "blackbox_event",
                                      (COMPONENT, "event", "{}"), None,
                                      {"event": "config_applied", "version": version.version})])

    # ---- writer thread ------------------------------------------------------------------------

    def _run(self) -> None:
        next_retention = 0.0
        # Commits start every commit_interval, however long the previous one took, so a
        # crash loses at most that interval (or the one commit that runs late under load).
        next_commit = _time.monotonic() + self.commit_interval
        while True:
            self._wake.wait(max(0.0, next_commit - _time.monotonic()))
            self._wake.clear()
            stopping = self._stop.is_set()
            now = _time.monotonic()
            if now >= next_commit:  # else woken early by commit_rows: the deadline stays
                next_commit = max(next_commit + self.commit_interval, now)
            try:
                self._write_pending()
                now = _time.monotonic()
                if self._store is not None and (now >= next_retention or stopping):
                    next_retention = now + self.retention_interval
                    self._enforce_budget()
            except Exception as exc:  # the writer thread must never die silently
                self._fail(f"recorder error: {type(exc).__name__}: {exc}")
            if stopping and not self._queue:
                break
        if self._store is not None:
            with contextlib.suppress(Exception):
                self._store.close()
            self._store = None

    def _take_queue(self) -> list[Capture]:
        captures: list[Capture] = []
        backlog = self._backlog
        while self._queue:
            item = self._queue.popleft()
            if isinstance(item, Capture):
                captures.append(item)
                continue
            with self._count_lock:
                self._queued_rows -= len(item)
            for row in item:
                obs = row[4]
                if isinstance(obs, Observation):
                    kind = row[1]
                    backlog.append((row[0], kind, row[2], int(obs.code), _encoded(obs, kind)))
                else:
                    backlog.append(cast(RowTuple, row))
        limit = self.queue_limit
        if len(backlog) > limit:
            kept = [r for r in backlog if r[1] != "sample"]
            if len(kept) > limit:
                kept = kept[-limit:]
            self.dropped += len(self._backlog) - len(kept)
            self._backlog = kept
        return captures

    def _write_pending(self) -> None:
        captures = self._take_queue()
        store = self._store
        if store is None:
            if _time.monotonic() < self._next_retry:
                self._keep_captures(captures)
                return
            if not self._open_store(initial=False):
                self._keep_captures(captures)
                return
            store = self._store
            assert store is not None
        for capture in captures:
            self._write_snapshot(capture)
        if not self._backlog:
            self._poll_imports(store)
            return
        rows = self._backlog
        try:
            store.append(rows)
        except (sqlite3.Error, OSError) as exc:
            self._storage_trouble(exc)
            return
        self.written += len(rows)
        self._backlog = []
        if self._error is not None:
            self._recovered()
        self._poll_imports(store)

    def _keep_captures(self, captures: list[Capture]) -> None:
        # No disk to write them to; the captures stay queued (they are already bounded).
        for c in captures:
            self._queue.append(c)

    def _storage_trouble(self, exc: BaseException) -> None:
        text = str(exc)
        corrupt = isinstance(exc, sqlite3.DatabaseError) and \
            not isinstance(exc, sqlite3.OperationalError)
        if corrupt or "malformed" in text or "not a database" in text:
            self._corrupt_during_run(text)
            return
        self._fail(f"cannot write health log {self.path}: {text}")

    def _corrupt_during_run(self, text: str) -> None:
        store = self._store
        self._store = None
        if store is not None:
            with contextlib.suppress(Exception):
                store.close()
        self._set_aside_and_reopen(text)

    def _fail(self, message: str) -> None:
        if self._error is None:
            self._error_since = self.clock()
            self._self_events.append(BlackBoxEvent(self._error_since, "storage_error", message,
                                                   COMPONENT))
        self._error = message
        self._next_retry = _time.monotonic() + self.retry_interval
        if self._store is not None and ("full" in message or "I/O" in message):
            # Drop the connection: a fresh one re-reads the file after space returns.
            with contextlib.suppress(Exception):
                self._store.close()
            self._store = None

    def _recovered(self) -> None:
        message = (f"writing health log {self.path} again after: {self._error}; "
                   f"{self.dropped} records dropped so far")
        now = self.clock()
        self._self_events.append(BlackBoxEvent(now, "storage_resumed", message, COMPONENT))
        rows = [Row(self._error_since or now, "blackbox_event", (COMPONENT, "event", "{}"),
                    int(Code.GENERAL_ERROR), {"event": "storage_error", "message": self._error}),
                Row(now, "blackbox_event", (COMPONENT, "event", "{}"), int(Code.GENERAL_OK),
                    {"event": "storage_resumed", "dropped": self.dropped})]
        self._error = None
        self._error_since = None
        store = self._store
        if store is not None:
            try:
                store.append(rows)
                self.written += len(rows)
            except (sqlite3.Error, OSError) as exc:
                self._storage_trouble(exc)

    def _open_store(self, initial: bool) -> bool:
        try:
            store = Store.open(self.path, durability=self.durability)
        except StoreCorrupt as exc:
            return self._set_aside_and_reopen(str(exc))
        except StorageError as exc:
            self._fail(str(exc))
            return False
        self._attach(store)
        return True

    def _set_aside_and_reopen(self, reason: str) -> bool:
        try:
            aside = set_aside(self.path)
        except OSError as exc:
            self._fail(f"health log {self.path} is corrupt ({reason}) and cannot be moved "
                       f"aside: {exc}")
            return False
        message = (f"health log {self.path} was corrupt ({reason}); moved to {aside.name} "
                   "and started a new one")
        now = self.clock()
        self._self_events.append(BlackBoxEvent(now, "storage_corrupt", message, COMPONENT))
        try:
            store = Store.open(self.path, durability=self.durability)
        except StorageError as exc:  # never a loop: stay failing and retry later
            self._fail(f"{message}, but the new one failed too: {exc}")
            return False
        self._attach(store)
        self._backlog.insert(0, Row(now, "blackbox_event", (COMPONENT, "event", "{}"),
                                    int(Code.GENERAL_ERROR),
                                    {"event": "storage_corrupt", "message": message,
                                     "set_aside": aside.name}))
        return True

    def _attach(self, store: Store) -> None:
        self._store = store
        with contextlib.suppress(sqlite3.Error):
            store.set_meta("robot_id", self.robot_id)
        self._seen_config_id = self._latest_config_id(store)
        with contextlib.suppress(sqlite3.Error, OSError):
            self.used_bytes = store.used_bytes()

    @staticmethod
    def _latest_config_id(store: Store) -> int:
        latest = store.latest("config")
        return latest.id if latest else 0

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
                self._configs.append(ConfigVersion(version, entry.time,
                                                   str(entry.payload.get("text", "")),
                                                   "import", entry.id))

    def _enforce_budget(self) -> None:
        store = self._store
        assert store is not None
        try:
            report = self.retention.enforce(store)
            self.used_bytes = report.after_bytes
            if report.acted:
                store.append([Row(self.clock(), "blackbox_event", (COMPONENT, "event", "{}"),
                                  None, {"event": "retention", "thinned": report.thinned,
                                         "dropped": report.dropped,
                                         "before_bytes": report.before_bytes,
                                         "after_bytes": report.after_bytes})])
        except (sqlite3.Error, OSError) as exc:
            self._storage_trouble(exc)
            return
        if self.ring is not None and self.snapshot_dir.exists():
            removed = enforce_directory(self.snapshot_dir, self._snapshot_budget)
            if removed:
                self._backlog.append(Row(self.clock(), "blackbox_event",
                                         (COMPONENT, "event", "{}"), None,
                                         {"event": "snapshots_deleted",
                                          "files": [p.name for p in removed]}))

    def _write_snapshot(self, capture: Capture) -> None:
        path = self.snapshot_dir / capture.name
        payload: dict[str, Any] = {"file": capture.name, "format": self.snapshot_format,
                                   "trigger": capture.trigger, "end": capture.end,
                                   "dropped_messages": capture.dropped}
        try:
            result = WRITERS[self.snapshot_format](capture.messages, capture.schemas, path)
        except Exception as exc:
            payload["error"] = f"{type(exc).__name__}: {exc}"
            self._self_events.append(BlackBoxEvent(self.clock(), "snapshot_error",
                                                   f"cannot write snapshot {path}: {exc}",
                                                   COMPONENT))
        else:
            self.snapshots_written += 1
            payload.update(messages=result.messages, bytes=result.bytes,
                           topics=list(result.topics), skipped_topics=list(result.skipped_topics))
        self._backlog.append(Row(capture.trigger, "snapshot", None, None, payload))


def _encoded(obs: Observation, kind: str) -> str:
    """A logged observation's payload as JSON; never raises, so no row can block the log."""
    try:
        return dumps(observation_payload(obs, kind != "sample"))
    except (TypeError, ValueError, RecursionError) as exc:
        return dumps({"code_name": obs.code.name, "message": obs.message,
                      "unencodable": f"{type(exc).__name__}: {exc}"})


# ---- the native `recorder:` section ------------------------------------------------------------

_UNITS = {"b": 1, "kb": 1000, "mb": 1000**2, "gb": 1000**3, "tb": 1000**4,
          "kib": 1024, "mib": 1024**2, "gib": 1024**3, "tib": 1024**4}


def parse_size(text: str) -> int:
    """``"1 GB"``, ``"512MiB"``, ``"1000000"`` -> bytes."""
    s = text.strip().lower().replace("_", "")
    num = s.rstrip("abcdefghijklmnopqrstuvwxyz").strip()
    unit = s[len(num):].strip() or "b"
    if unit not in _UNITS:
        raise ValueError(f"unknown size unit {unit!r}; use B, KB, MB, GB, TB, KiB, MiB, GiB")
    try:
        value = float(num)
    except ValueError:
        raise ValueError(f"not a size: {text!r}") from None
    if value < 0:
        raise ValueError(f"a size cannot be negative: {text!r}")
    return int(value * _UNITS[unit])


def _size(node: ConfigNode) -> int:
    raw = node.raw
    if isinstance(raw, int) and not isinstance(raw, bool):
        return node.int(min=1)
    if isinstance(raw, str):
        try:
            return parse_size(raw)
        except ValueError as exc:
            raise node.error(str(exc)) from None
    raise node.error("expected a size in bytes or a text like '1 GB'")


def _boost(node: ConfigNode | None, default: FaultBoost | None) -> FaultBoost | None:
    if node is None:
        return default
    if not node.is_map and node.raw is False:
        return None
    node.check_keys(["interval", "duration", "snapshot"])
    base = default or FaultBoost()
    return FaultBoost(
        interval=node["interval"].float(min=0, min_exclusive=True) if node.get("interval")
        else base.interval,
        duration=node["duration"].float(min=0) if node.get("duration") else base.duration,
        snapshot=node["snapshot"].bool() if node.get("snapshot") is not None else base.snapshot,
    )


def _rule(node: ConfigNode, base: PolicyRule, matching: bool) -> PolicyRule:
    keys = ["interval", "on_fault", "states"] + (["entity", "characteristic"] if matching else [])
    node.check_keys(keys)
    interval: float | None = base.interval
    if "interval" in node:
        iv = node.get("interval")
        interval = None if iv is None or (not iv.is_map and iv.raw is False) else \
            iv.float(min=0, min_exclusive=True)
    states: dict[str, float] = dict(base.states)
    if node.get("states") is not None:
        for key, child in node["states"].items():
            states[key] = child.float(min=0, min_exclusive=True)
    return PolicyRule(
        entity=node["entity"].str() if matching and node.get("entity") else "*",
        characteristic=node["characteristic"].str() if matching and node.get("characteristic")
        else "*",
        interval=interval,
        on_fault=_boost(node.get("on_fault"), base.on_fault) if "on_fault" in node
        else base.on_fault,
        states=states,
    )


def policy_from_config(node: ConfigNode | None) -> LoggingPolicy:
    if node is None:
        return LoggingPolicy()
    node.check_keys(["interval", "on_fault", "states", "rules"])
    default = _rule(ConfigNode.mapping({k: v for k, v in node.items() if k != "rules"}, node),
                    PolicyRule(), matching=False)
    rules: list[PolicyRule] = []
    if node.get("rules") is not None:
        for item in node["rules"].list():
            if "entity" not in item and "characteristic" not in item:
                raise item.error("a rule needs 'entity' or 'characteristic' (globs) to match")
            rules.append(_rule(item, default, matching=True))
    return LoggingPolicy(tuple(rules), default)


def snapshot_from_config(node: ConfigNode | None) -> tuple[SnapshotConfig | None, dict[str, Any]]:
    if node is None:
        return SnapshotConfig(), {}
    if not node.is_map:
        if node.raw is False:
            return None, {}
        raise node.error("expected a mapping or false")
    node.check_keys(["enabled", "format", "before", "after", "max_bytes", "include", "exclude",
                     "keep_one_of", "directory", "share", "cooldown"])
    if node.get("enabled") is not None and not node["enabled"].bool():
        return None, {}
    base = SnapshotConfig()
    keep: dict[str, int] = {}
    if node.get("keep_one_of") is not None:
        for topic, child in node["keep_one_of"].items():
            keep[topic] = child.int(min=1)
    cfg = SnapshotConfig(
        before=node["before"].float(min=0) if node.get("before") else base.before,
        after=node["after"].float(min=0) if node.get("after") else base.after,
        max_bytes=_size(node["max_bytes"]) if node.get("max_bytes") else base.max_bytes,
        include=node["include"].str_list() if node.get("include") else base.include,
        exclude=node["exclude"].str_list() if node.get("exclude") else base.exclude,
        keep_one_of=keep,
    )
    extra: dict[str, Any] = {}
    if node.get("format"):
        extra["snapshot_format"] = node["format"].str(list(WRITERS))
    if node.get("directory"):
        extra["snapshot_dir"] = node["directory"].str()
    if node.get("share"):
        extra["snapshot_share"] = node["share"].float(min=0, max=0.9)
    if node.get("cooldown") is not None:
        extra["snapshot_cooldown"] = node["cooldown"].float(min=0)
    return cfg, extra


def recorder_options(section: ConfigNode | None, base_dir: Path) -> dict[str, Any]:
    """Keyword arguments of :class:`Recorder` from a ``recorder:`` section."""
    opts: dict[str, Any] = {"path": base_dir / "blackbox.db"}
    if section is None:
        opts["snapshot"] = SnapshotConfig()
        return opts
    section.check_keys(["path", "budget", "commit_interval", "durability", "queue_limit",
                        "policy", "snapshot"])
    if section.get("path"):
        opts["path"] = base_dir / section["path"].str()
    if section.get("budget"):
        opts["budget_bytes"] = _size(section["budget"])
    if section.get("commit_interval"):
        opts["commit_interval"] = section["commit_interval"].float(min=0.01, max=60)
    if section.get("durability"):
        opts["durability"] = section["durability"].str(["full", "normal"])
    if section.get("queue_limit"):
        opts["queue_limit"] = section["queue_limit"].int(min=100)
    opts["policy"] = policy_from_config(section.get("policy"))
    snap, extra = snapshot_from_config(section.get("snapshot"))
    opts["snapshot"] = snap
    if "snapshot_dir" in extra:
        extra["snapshot_dir"] = base_dir / extra["snapshot_dir"]
    opts.update(extra)
    return opts
