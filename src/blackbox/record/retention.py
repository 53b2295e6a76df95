"""Keeping the health log inside its disk budget, and predicting how long the budget lasts.

When the log grows past its budget, the least valuable data goes first: old periodic
samples are thinned (three of every four removed, so the oldest history gets coarser,
not shorter), then dropped oldest first; only then state changes and diagnoses; events,
failures and configurations last. Thinning keeps one in four rather than one in two on
purpose: SQLite merges a page with its neighbours only when it falls below a third full,
so only a heavy thinning actually frees pages.
"""

from __future__ import annotations

import stat
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from blackbox.record.store import KINDS, Store

SNAPSHOT_SUFFIXES = (".bag", ".mcap")

_SAMPLE = KINDS["sample"]
_CHANGES = (KINDS["observation"], KINDS["exceedance"], KINDS["diagnosis"], KINDS["snapshot"])
_LAST = (KINDS["failure"], KINDS["blackbox_event"])
_BY_VALUE = ((_SAMPLE,), _CHANGES, _LAST, (KINDS["config"],))
"""Kinds of entries, least valuable first: what retention drops first."""


class RetentionStore(Protocol):
    """What retention needs of the recorder's store; its SQL stays inside the store."""

    def used_bytes(self) -> int: ...

    def reclaim(self) -> None: ...

    def thin_samples(self, kind: int) -> int: ...

    def drop_least_valuable(self, kinds_by_value: Sequence[Sequence[int]]) -> int: ...


@dataclass(frozen=True, slots=True)
class RetentionReport:
    before_bytes: int
    after_bytes: int
    thinned: int = 0
    dropped: int = 0

    @property
    def acted(self) -> bool:
        return bool(self.thinned or self.dropped)


@dataclass(frozen=True, slots=True)
class Retention:
    """A disk budget for the log file. Acts above ``high`` x budget, stops below ``low``."""

    budget_bytes: int
    high: float = 0.95
    low: float = 0.85
    max_steps: int = 200

    def over(self, store: RetentionStore) -> bool:
        return store.used_bytes() > self.budget_bytes * self.high

    def enforce(self, store: RetentionStore) -> RetentionReport:
        before = store.used_bytes()
        if before <= self.budget_bytes * self.high:
            return RetentionReport(before, before)
        target = self.budget_bytes * self.low
        thinned = dropped = 0
        used = before
        for _ in range(self.max_steps):
            if used <= target:
                break
            n = store.thin_samples(_SAMPLE)
            if n:
                thinned += n
            else:
                n = store.drop_least_valuable(_BY_VALUE)
                if not n:
                    break
                dropped += n
            store.reclaim()
            used = store.used_bytes()
        return RetentionReport(before, used, thinned, dropped)

def enforce_directory(directory: Path, budget_bytes: int, ours: Sequence[str]) -> list[str]:
    """Delete the oldest of *our* snapshot files until they fit ``budget_bytes``.

    ``ours`` is the log's manifest, oldest first: the names the recorder wrote. Nothing else
    in ``directory`` is ever deleted (or counted): a name must be a plain file name with a
    snapshot suffix, and the file a regular file, not a link. Returns the deleted names.
    """
    files: list[tuple[str, Path, int]] = []
    for name in ours:
        if Path(name).name != name or not name.endswith(SNAPSHOT_SUFFIXES) or \
                name.startswith("."):
            continue
        path = directory / name
        try:
            info = path.lstat()
        except OSError:
            continue
        if stat.S_ISREG(info.st_mode):
            files.append((name, path, info.st_size))
    total = sum(size for _, _, size in files)
    removed: list[str] = []
    for name, path, size in files:
        if total <= budget_bytes:
            break
        try:
            path.unlink()
        except OSError:
            continue
        total -= size
        removed.append(name)
    return removed


# ---- capacity ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ObservedCharacteristic:
    """One observer of a configuration, as far as the log's size is concerned.

    ``values``: numbers per observation (:class:`~blackbox.observe.base.ObserverKind`
    ``logged_values``); ``on_node``: ``entity`` names a node, not a topic.
    """

    entity: str
    characteristic: str
    every: float = 1.0
    values: int = 2
    on_node: bool = False


@dataclass(frozen=True, slots=True)
class CapacityEstimate:
    observers: int
    bytes_per_hour: float
    entries_per_hour: float
    budget_bytes: int
    simulated_hours: float
    faults_per_hour: float

    @property
    def hours(self) -> float:
        return self.budget_bytes / self.bytes_per_hour if self.bytes_per_hour else float("inf")


def thesis_robot() -> list[ObservedCharacteristic]:
    """The thesis experiment: 3 nodes, 10 observers evaluated at 1 Hz (Appendix B)."""
    out = [ObservedCharacteristic(n, "activated", values=0, on_node=True)
           for n in ("/audio_capture", "/usb_cam", "/Signal_generator")]
    for topic in ("/audio", "/usb_cam/image_raw", "/signal"):
        out.append(ObservedCharacteristic(topic, "hz"))
        out.append(ObservedCharacteristic(topic, "timeout", values=1))
    out.append(ObservedCharacteristic("/signal", "scores"))
    return out


def hundred_topic_robot() -> list[ObservedCharacteristic]:
    """100 topics (rate and timeout each) and 25 nodes (alive, CPU/memory): 250 observers."""
    out: list[ObservedCharacteristic] = []
    for i in range(100):
        out.append(ObservedCharacteristic(f"/robot/topic_{i:03d}", "hz"))
        out.append(ObservedCharacteristic(f"/robot/topic_{i:03d}", "timeout", values=1))
    for i in range(25):
        node = f"/robot/node_{i:02d}"
        out.append(ObservedCharacteristic(node, "activated", values=0, on_node=True))
        out.append(ObservedCharacteristic(node, "resources", values=4, on_node=True))
    return out


def estimate_capacity(observers: list[ObservedCharacteristic], budget_bytes: int,
                      policy: object | None = None, *, faults_per_hour: float = 1.0,
                      fault_seconds: float = 10.0, simulated_hours: float = 1.0,
                      workdir: Path | None = None) -> CapacityEstimate:
    """Measure bytes per operating hour by recording a simulated run into a real log.

    Every observer reports at its interval with realistic values; ``faults_per_hour``
    times an hour one observer (in turn) is faulty for ``fault_seconds``, which adds the
    state changes, the event-driven samples, a diagnosis and failure entries. The log is
    written through the same policy and store as in operation, so the result includes
    SQLite's own overhead (indexes, page fill).
    """
    import random
    import tempfile

    from blackbox.model import Code, Observation, Resource, State
    from blackbox.record.policy import LoggingPolicy, PolicyTracker, observation_payload
    from blackbox.record.store import Row

    tracker = PolicyTracker(policy if isinstance(policy, LoggingPolicy) else LoggingPolicy())
    rng = random.Random(7)
    span = simulated_hours * 3600.0
    n_faults = max(0, round(faults_per_hour * simulated_hours))
    faults = [(span * (k + 0.5) / n_faults, observers[k % len(observers)]) for k in
              range(n_faults)] if observers else []
    resources = {o: Resource(node=o.entity) if o.on_node else Resource(topic=o.entity)
                 for o in observers}
    names = [f"value_{k}" for k in range(8)]
    ok = (State(1, "ok"),)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        store = Store.open(Path(tmp) / "capacity.db", durability="normal", check=False)
        store.checkpoint()
        empty = store.used_bytes()
        rows: list[Row] = []
        entries = 0
        t0 = 1.7e9
        step = min((o.every for o in observers), default=1.0)
        ticks = int(span / step)
        for i in range(ticks):
            t = i * step
            for o in observers:
                if (t / o.every) % 1.0 > 1e-9 and abs((t / o.every) % 1.0 - 1.0) > 1e-9:
                    continue
                faulty = any(ft <= t < ft + fault_seconds and fo is o for ft, fo in faults)
                values = {names[k]: rng.gauss(1.0, 0.05) for k in range(o.values)}
                obs = Observation(t0 + t, o.characteristic, resources[o],
                                  Code.NO_STATE_FITS if faulty else Code.GENERAL_OK,
                                  () if faulty else ok, values)
                d = tracker.decide(obs)
                if d is not None:
                    rows.append(Row(obs.time, d.kind, d.channel, int(obs.code),
                                    observation_payload(obs, d.kind != "sample")))
            for ft, fo in faults:
                if t == int(ft / step) * step or t == int((ft + fault_seconds) / step) * step:
                    start = t < ft + fault_seconds - step
                    comps = [fo.entity] if start else []
                    rows.append(Row(t0 + t, "diagnosis", None, None,
                                    {"candidates": [comps] if comps else [], "failed": [],
                                     "explanation": "", "complete": True}))
                    rows.append(Row(t0 + t, "failure", None, None,
                                    {"components": [fo.entity],
                                     "category": "detection" if start else "rectification"}))
            if len(rows) >= 5000:
                entries += len(rows)
                store.append(rows)
                rows = []
        entries += len(rows)
        store.append(rows)
        store.checkpoint()
        used = store.used_bytes() - empty
        store.close()
    return CapacityEstimate(len(observers), used / simulated_hours, entries / simulated_hours,
                            budget_bytes, simulated_hours, faults_per_hour)
