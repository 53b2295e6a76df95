"""The black box recorder: a sink that keeps the health log, whatever happens to the disk.

The pipeline thread only decides what to keep (policy), hands the kept observations to
the writer thread (:mod:`blackbox.record.handoff`, bounded) and feeds the snapshot ring
buffer: nothing on that path touches the disk or encodes anything, so a slow, full or
broken disk never delays observation (unless the run asked to wait for the disk: a
simulated clock). The writer thread (:mod:`blackbox.record.writer`) commits, keeps the
budget and survives disk failures; snapshot files are written on a thread of their own
(:mod:`blackbox.record.capture_writer`). Settings: :mod:`blackbox.record.settings`.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import time as _time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from blackbox.config.node import ConfigNode
from blackbox.events import MessageArrival, TopicSchema
from blackbox.health.identity import EventLedger
from blackbox.model import BlackBoxEvent, Code, Diagnosis, Observation, Resource
from blackbox.record.handoff import Handoff, Pending
from blackbox.record.logfile import check_record_path, safe_name
from blackbox.record.policy import LoggingPolicy, PolicyTracker, observation_payload
from blackbox.record.retention import Retention
from blackbox.record.settings import RecorderSettings
from blackbox.record.snapshot import SUFFIXES, Capture, RingBuffer
from blackbox.record.store import Row
from blackbox.record.writer import COMPONENT, ConfigVersion, LogWriter, own_event
from blackbox.sinks import SinkBase

RESOURCE = Resource(node="/blackbox/recorder")
_SNAPSHOT_MODULES = {"ros1": "rosbags.rosbag1", "mcap": "mcap.writer"}

__all__ = ["COMPONENT", "RESOURCE", "ConfigVersion", "Recorder", "config_entry_row"]


def config_entry_row(now: float, text: str, source: str, **extra: Any) -> Row:
    """A configuration version; ``version`` is assigned when it is written."""
    payload = {"version": None, "source": source,
               "sha256": hashlib.sha256(text.encode()).hexdigest(), "text": text, **extra}
    return Row(now, "config", None, None, payload)


class Recorder(SinkBase):
    """Sink writing the health log at ``settings.path`` and snapshots beside it.

    Raises :class:`~blackbox.record.logfile.RecordPathError` when the path cannot hold a
    log or holds a file that is not one (see docs/recorder.md). Callbacks
    ``on_self_event`` (the recorder's own failures and recoveries) and ``on_config``
    (configurations imported while running) are called on the pipeline thread, from
    inside the next ``on_*`` call, never from the writer thread and never from
    :meth:`close` (the other sinks may be closed by then; such events are in the log).
    """

    def __init__(
        self,
        settings: RecorderSettings,
        *,
        robot_id: str,
        schema_lookup: Callable[[str], TopicSchema | None] | None = None,
        clock: Callable[[], float] = _time.time,
        on_self_event: Callable[[BlackBoxEvent], None] | None = None,
        on_config: Callable[[ConfigVersion], None] | None = None,
        ledger: EventLedger | None = None,
    ) -> None:
        self.settings = settings
        self.ledger = ledger if ledger is not None else EventLedger()
        """Event identities: shared with the health publisher, which assigns them (the
        recorder looks them up, so its own rows never open a hole in the sequence); without
        one the recorder is the only consumer and assigns them itself."""
        self._assigns_ids = ledger is None
        self.robot_id = robot_id
        self.schema_lookup = schema_lookup
        self.clock = clock
        self.on_self_event = on_self_event
        self.on_config = on_config
        snap = settings.snapshot
        self.snapshot_format = (snap.format or "ros1") if snap is not None else None
        self.replaced = check_record_path(settings.path,
                                          replace_foreign=settings.replace_foreign)
        self.ring = RingBuffer(snap.ring) if snap is not None else None
        self.wants_messages = self.ring is not None
        if self.snapshot_format is not None:
            # Imported now, not on the writer's first snapshot in the middle of a fault.
            importlib.import_module(_SNAPSHOT_MODULES[self.snapshot_format])
        self._tracker = PolicyTracker(settings.policy)
        self._last_capture_end = float("-inf")
        self._last_diagnosis: tuple[frozenset[str], ...] | None = None
        self._last_failure: frozenset[str] = frozenset()
        self._closed = False
        self._handoff = Handoff(settings.queue_limit, settings.overflow, settings.commit_rows)
        self._writer = LogWriter(settings, robot_id, self._handoff, clock, self.snapshot_format)
        self._handoff.on_full = self._writer.wake.set
        start = {"event": "start", "robot_id": robot_id, "pid": os.getpid()}
        if self.replaced is not None:  # --force: say where the other file went
            start["moved_aside"] = str(self.replaced)
        self._queue_rows([own_event(self.clock(), start)], force=True)
        self._writer.start()

    # ---- configuration ----------------------------------------------------------------------

    @classmethod
    def from_config(cls, section: ConfigNode | None, robot_id: str, base_dir: str | Path,
                    **kwargs: Any) -> Recorder:
        """A recorder from a native ``recorder:`` section (see docs/recorder.md)."""
        return cls(RecorderSettings.from_config(section, Path(base_dir)), robot_id=robot_id,
                   **kwargs)

    def record_config(self, text: str, source: str = "startup", **extra: Any) -> None:
        """Store a configuration version (the one the black box starts with, say)."""
        self._queue_rows([config_entry_row(self.clock(), text, source, **extra)])

    # ---- what the rest of the black box reads ----------------------------------------------

    @property
    def path(self) -> Path:
        return self.settings.path

    @property
    def snapshot_dir(self) -> Path:
        return self.settings.snapshot_dir

    @property
    def policy(self) -> LoggingPolicy:
        return self.settings.policy

    @property
    def commit_interval(self) -> float:
        return self.settings.commit_interval

    @property
    def retention(self) -> Retention:
        return self._writer.retention

    @property
    def dropped(self) -> int:
        return self._handoff.dropped_total

    @property
    def written(self) -> int:
        return self._writer.written

    @property
    def pending(self) -> int:
        """Rows handed to the writer and not yet committed (0: everything so far is in the
        log file)."""
        return self._handoff.pending

    @property
    def snapshots_written(self) -> int:
        captures = self._writer.captures
        return captures.written if captures is not None else 0

    @property
    def used_bytes(self) -> int:
        return self._writer.used_bytes

    @property
    def failing(self) -> bool:
        return self._writer.error is not None

    def health(self) -> Observation:
        """The recorder's own observation: ``GENERAL_ERROR`` while it cannot write."""
        values = {"queued_rows": float(self._handoff.pending), "dropped": float(self.dropped),
                  "written": float(self.written), "used_bytes": float(self.used_bytes)}
        error = self._writer.error
        if error:
            return Observation(self.clock(), "recorder", RESOURCE, Code.GENERAL_ERROR,
                               values=values, message=error)
        return Observation(self.clock(), "recorder", RESOURCE, Code.GENERAL_OK, values=values)

    # ---- sink -------------------------------------------------------------------------------

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        rows: list[Pending] = []
        decide = self._tracker.decide
        for obs in observations:
            d = decide(obs)
            if d is None:
                continue
            event_id = self._event_id(obs, d.fault_started, d.channel[2]) \
                if d.kind != "sample" else None
            if (d.snapshot and self.ring is not None) or event_id is not None:
                payload = observation_payload(obs, True)
                if d.snapshot and self.ring is not None:
                    path = self._trigger_snapshot(obs.time,
                                                  f"{obs.observer} {obs.resource.label()}")
                    if path:
                        payload["snapshot"] = path
                if event_id is not None:
                    payload["event_id"] = event_id
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
                                       {"candidates": [sorted(c) for c in cands],
                                        "failed": failed, "explanation": diagnosis.explanation,
                                        "complete": diagnosis.complete,
                                        "engine": diagnosis.engine,
                                        "agreement": diagnosis.agreement})]
            best = cands[0] if cands else frozenset()
            if best != self._last_failure:
                payload: dict[str, Any] = {"components": sorted(best)}
                if best:
                    payload["category"] = "detection"
                    payload["explanation"] = diagnosis.explanation
                    if self.ring is not None:
                        payload["snapshot"] = self._trigger_snapshot(
                            diagnosis.time, "failure " + ",".join(sorted(best)))
                else:
                    payload["category"] = "rectification"
                    payload["components"] = sorted(self._last_failure)
                payload["events"] = self._diagnosis_events(diagnosis.time, best)
                self._last_failure = best
                rows.append(Row(diagnosis.time, "failure", None, None, payload))
            self._queue_rows(rows)
        self._after_call(diagnosis.time)

    def _event_id(self, obs: Observation, started: bool, resource: str) -> str | None:
        """The identity of the event ``obs`` starts (a fault's onset, or a change of state
        the health publisher announced), if it is one."""
        key = f"{obs.observer}|{resource}"
        if self._assigns_ids:
            return str(self.ledger.assign("exceedance", key, obs.time)) if started else None
        found = self.ledger.lookup("exceedance" if obs.code < 0 else "state_change", key,
                                   obs.time)
        return str(found) if found is not None else None

    def _diagnosis_events(self, t: float, best: frozenset[str]) -> list[dict[str, str]]:
        """The failures and rectifications this diagnosis caused, with their identities."""
        if self._assigns_ids:
            named = [("failure", c, self.ledger.assign("failure", c, t))
                     for c in sorted(best - self._last_failure)]
            named += [("rectification", c, self.ledger.assign("rectification", c, t))
                      for c in sorted(self._last_failure - best)]
        else:
            named = self.ledger.at(t, ("failure", "rectification"))
        return [{"kind": k, "entity": c, "id": str(i)} for k, c, i in named]

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
        """Finish open snapshots, write everything queued and close the log.

        Self-events still pending are delivered first; what happens while closing is
        written to the log only.
        """
        if self._closed:
            return
        self._closed = True
        self._deliver()
        self.on_self_event = None
        self.on_config = None
        if self.ring is not None:
            for capture in self.ring.flush():
                self._hand_over(capture)
        self._queue_rows([own_event(self.clock(), {"event": "stop", "dropped": self.dropped})],
                         force=True)
        self._handoff.close()
        self._writer.stop(timeout)

    # ---- pipeline-thread helpers --------------------------------------------------------------

    def _queue_rows(self, rows: list[Pending], force: bool = False) -> None:
        wake = self._handoff.put(rows, force)
        if wake and self._writer.error is None and not self._writer.wake.is_set():
            self._writer.wake.set()  # while the disk fails, retries stay one per interval

    def _trigger_snapshot(self, time: float, reason: str) -> str | None:
        ring = self.ring
        assert ring is not None and self.snapshot_format is not None
        running = ring.active(time)
        if running is not None:
            return running.name
        assert self.settings.snapshot is not None
        if time < self._last_capture_end + self.settings.snapshot.cooldown:
            return None
        stamp = datetime.fromtimestamp(max(time, 0.0), UTC)
        name = (f"{safe_name(self.robot_id)}-{stamp:%Y%m%dT%H%M%S}-"
                f"{int(time * 1000) % 1000:03d}{SUFFIXES[self.snapshot_format]}")
        capture = ring.trigger(time, name)
        self._last_capture_end = capture.end
        return name

    def _after_call(self, now: float) -> None:
        ring = self.ring
        if ring is not None:
            for capture in ring.complete(now):
                self._hand_over(capture)
        writer = self._writer
        if writer.events or writer.configs:
            self._deliver()

    def _hand_over(self, capture: Capture) -> None:
        lookup = self.schema_lookup
        for topic in {h.topic for h in capture.messages}:
            capture.schemas[topic] = lookup(topic) if lookup else None
        self._handoff.put_capture(capture)

    def _deliver(self) -> None:
        events, configs = self._writer.events, self._writer.configs
        while events:
            event = events.popleft()
            if self.on_self_event is not None:
                self.on_self_event(event)
        while configs:
            version = configs.popleft()
            if self.on_config is None:
                continue
            try:
                self.on_config(version)
            except Exception as exc:
                self._queue_rows([own_event(self.clock(), {
                    "event": "config_rejected", "version": version.version,
                    "message": str(exc)})])
            else:
                self._queue_rows([own_event(self.clock(), {
                    "event": "config_applied", "version": version.version})])
