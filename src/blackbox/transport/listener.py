"""The station side: everything the robots on a domain say, kept as live state.

The view holds per robot (UCMS resource id) its entities, characteristics and latest events,
joined by source id. It trusts nothing it receives: every sample is handled on its own,
references to unknown ids are kept until the referenced sample arrives, and a sample that
cannot be interpreted is counted and dropped. A view that starts late gets the durable
state from the writers (transient-local) and, when ``backfill`` is set, asks each robot
for the events it missed through a log request.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.util import duration

from blackbox.health.extension import (
    C_Characteristic_Extension,
    C_Entity_Description,
    C_Event_Extension,
    T_EventKind,
)
from blackbox.health.types import (
    C_Failure_Event,
    C_Monitored_Characteristic,
    C_Monitored_Characteristic_Specification,
    C_Monitored_Entity,
    C_Threshold,
    C_Threshold_Exceedence_Event,
    T_IdentifierType,
    T_Monitored_Entity_StateType,
    seconds_of,
)
from blackbox.transport.logservice import LogClient
from blackbox.transport.participant import Bus

HEALTH_NAMES = ("OPERATIONAL", "DEGRADED", "NOT_OPERATIONAL", "UNKNOWN")
LISTENED = ("C_Monitored_Entity", "C_Monitored_Characteristic",
            "C_Monitored_Characteristic_Specification", "C_Threshold",
            "C_Threshold_Exceedence_Event", "C_Failure_Event", "BlackBox_Entity_Description",
            "BlackBox_Characteristic_Extension", "BlackBox_Event_Extension")


def _key(ident: T_IdentifierType) -> tuple[int, int]:
    return (int(ident.A_resourceId), int(ident.A_instanceId))


@dataclass
class EntityView:
    name: str = ""
    kind: str = ""
    health: str = "UNKNOWN"
    online: bool = True
    bit: bool = False
    characteristics: list[tuple[int, int]] = field(default_factory=list)
    failures: int = 0


@dataclass
class CharacteristicView:
    name: str = ""
    unit: str = ""
    value: float | None = None
    time: float | None = None
    entity: tuple[int, int] | None = None
    thresholds: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class EventView:
    time: float
    kind: str
    entity: str
    text: str
    origin: str = "live"


@dataclass
class RobotView:
    resource_id: int
    robot_id: str = ""
    entities: dict[tuple[int, int], EntityView] = field(default_factory=dict)
    characteristics: dict[tuple[int, int], CharacteristicView] = field(default_factory=dict)
    events: deque[EventView] = field(default_factory=lambda: deque(maxlen=50))
    event_ids: set[tuple[int, int, str]] = field(default_factory=set)
    backfilled: bool = False

    def add_event(self, event: EventView, ident: tuple[int, int, str]) -> None:
        if ident in self.event_ids:
            return
        self.event_ids.add(ident)
        self.events.append(event)

    def name_of(self, ident: tuple[int, int] | None) -> str:
        entity = self.entities.get(ident) if ident else None
        if entity is None or ident is None:
            return f"#{ident[1]}" if ident else "?"
        return entity.name or f"#{ident[1]}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "robot_id": self.robot_id,
            "resource_id": self.resource_id,
            "entities": {e.name or f"#{k[1]}": {"health": e.health, "online": e.online,
                                                 "kind": e.kind, "bit": e.bit,
                                                 "failures": e.failures}
                         for k, e in self.entities.items()},
            "characteristics": {c.name or f"#{k[1]}": c.value
                                for k, c in self.characteristics.items()},
            "events": [{"time": e.time, "kind": e.kind, "entity": e.entity, "text": e.text,
                        "origin": e.origin} for e in self.events],
        }


class HealthListener:
    """Reads every UCMS and extension topic of one partition and keeps a view per robot."""

    def __init__(self, bus: Bus, *, backfill: float = 0.0, log_timeout: float = 5.0) -> None:
        self.bus = bus
        self.readers = {name: bus.reader(name) for name in LISTENED}
        self.robots: dict[int, RobotView] = {}
        self.backfill = backfill
        self.log_timeout = log_timeout
        self.rejected = 0
        self.received = 0
        self._pending_ext: dict[tuple[int, int], C_Event_Extension] = {}
        self._log: LogClient | None = LogClient(bus) if backfill > 0 else None
        self._waitset = WaitSet(bus.participant)
        mask = SampleState.NotRead | ViewState.Any | InstanceState.Any
        for reader in self.readers.values():
            self._waitset.attach(ReadCondition(reader, mask))

    def robot(self, ident: T_IdentifierType) -> RobotView:
        rid = int(ident.A_resourceId)
        view = self.robots.get(rid)
        if view is None:
            view = self.robots[rid] = RobotView(rid)
        return view

    def poll(self, timeout: float = 0.2) -> int:
        """Wait up to ``timeout`` s for data, take everything; returns samples handled."""
        self._waitset.wait(duration(seconds=timeout))
        handled = 0
        for reader in self.readers.values():
            try:
                samples = reader.take(N=256)
            except Exception:
                self.rejected += 1
                continue
            for sample in samples:
                handled += 1
                try:
                    self._handle(sample)
                    self.received += 1
                except Exception:
                    self.rejected += 1
        self._backfill()
        return handled

    def _handle(self, s: Any) -> None:
        info = getattr(s, "sample_info", None)
        if info is not None and not info.valid_data:
            return
        if isinstance(s, C_Monitored_Entity):
            view = self.robot(s.A_sourceID)
            e = view.entities.setdefault(_key(s.A_sourceID), EntityView())
            status = int(s.A_healthStatus.value)
            e.health = HEALTH_NAMES[status] if 0 <= status < len(HEALTH_NAMES) else "UNKNOWN"
            e.online = s.A_MonitoredEntityState == \
                T_Monitored_Entity_StateType.L_Monitored_Entity_StateType_ON
            e.bit = bool(s.A_bitInProgress)
            e.characteristics = [_key(i) for i in s.A_monitoredCharacteristics_sourceID]
            e.failures = len(s.A_failureEvents_sourceID)
        elif isinstance(s, C_Entity_Description):
            view = self.robot(s.A_sourceID)
            e = view.entities.setdefault(_key(s.A_sourceID), EntityView())
            e.name = s.A_name[:200]
            e.kind = s.A_kind[:20]
            if s.A_kind == "robot":
                view.robot_id = s.A_robotId[:200]
        elif isinstance(s, C_Monitored_Characteristic):
            view = self.robot(s.A_sourceID)
            c = view.characteristics.setdefault(_key(s.A_sourceID), CharacteristicView())
            c.value = float(s.A_value)
            c.time = seconds_of(s.A_timeOfDataGeneration)
            c.entity = _key(s.A_monitoredEntity_sourceID)
        elif isinstance(s, C_Monitored_Characteristic_Specification):
            view = self.robot(s.A_sourceID)
            for ident in s.A_specifiedCharacteristics_sourceID[:16]:
                c = view.characteristics.setdefault(_key(ident), CharacteristicView())
                c.unit = s.A_unit[:20]
                c.name = c.name or s.A_descriptor[:200]
        elif isinstance(s, C_Characteristic_Extension):
            view = self.robot(s.A_sourceID)
            c = view.characteristics.setdefault(_key(s.A_sourceID), CharacteristicView())
            c.name = s.A_name[:200]
        elif isinstance(s, C_Threshold):
            view = self.robot(s.A_sourceID)
            c = view.characteristics.setdefault(_key(s.A_concernedCharacteristic_sourceID),
                                                CharacteristicView())
            text = f"{s.A_name[:60]} {s.A_value:.4g}"
            if text not in c.thresholds:
                c.thresholds.append(text)
        elif isinstance(s, C_Threshold_Exceedence_Event):
            view = self.robot(s.A_sourceID)
            ck = _key(s.A_concernedCharacteristic_sourceID)
            concerned = view.characteristics.get(ck)
            ext = self._pending_ext.pop(_key(s.A_sourceID), None)
            kind = "state change" if ext is not None and \
                ext.A_kind == T_EventKind.L_EventKind_STATE_CHANGE else "exceedence"
            value = s.A_measuredValue
            text = f"{concerned.name if concerned else f'#{ck[1]}'} = " + \
                (f"{value:.4g}" if math.isfinite(value) else "n/a")
            view.add_event(EventView(seconds_of(s.A_eventOccurrenceDate), kind,
                                     view.name_of(concerned.entity if concerned else None), text),
                           (*_key(s.A_sourceID), "exceedance"))
        elif isinstance(s, C_Event_Extension):
            self._pending_ext[_key(s.A_sourceID)] = s
            if len(self._pending_ext) > 1000:
                self._pending_ext.pop(next(iter(self._pending_ext)))
        elif isinstance(s, C_Failure_Event):
            view = self.robot(s.A_sourceID)
            entity = view.name_of(_key(s.A_monitoredEntity_sourceID))
            text = s.A_failureDescription[:300]
            if s.A_causeDescription:
                text += f": {s.A_causeDescription[:300]}"
            view.add_event(EventView(seconds_of(s.A_eventOccurrenceDate), "failure", entity,
                                     text), (*_key(s.A_sourceID), "failure"))
        else:
            raise TypeError(f"unexpected sample {type(s).__name__}")

    def _backfill(self) -> None:
        if self._log is None:
            return
        for view in self.robots.values():
            if view.backfilled or not view.robot_id:
                continue
            view.backfilled = True
            self.fetch_missed(view)

    def fetch_missed(self, view: RobotView) -> int:
        """Ask the robot for its recorded exceedences and failures of the backfill window."""
        if self._log is None:
            self._log = LogClient(self.bus)
        answer = self._log.request(view.robot_id, since=time.time() - self.backfill,
                                   kinds=["exceedance", "failure"], timeout=self.log_timeout)
        added = 0
        for entry in answer.entries:
            try:
                kind = str(entry.get("kind"))
                t = float(entry.get("time", 0.0))
                payload = entry.get("payload") or {}
                entity = str(entry.get("entity") or ",".join(payload.get("components", [])))
                if kind == "failure":
                    text = f"{payload.get('category', 'failure')}: " + str(
                        payload.get("explanation") or "")
                else:
                    text = f"{entry.get('characteristic')} {payload.get('message', '')}"
                before = len(view.events)
                view.add_event(EventView(t, kind, entity, text.strip(), "log"),
                               (int(entry.get("id", 0)), 0, "log"))
                added += len(view.events) != before
            except (TypeError, ValueError, AttributeError):
                self.rejected += 1
        return added

    def to_dict(self) -> dict[str, Any]:
        return {"robots": {v.robot_id or f"#{rid}": v.to_dict() for rid, v in
                           sorted(self.robots.items())},
                "received": self.received, "rejected": self.rejected}
