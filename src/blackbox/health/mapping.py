"""From observations and diagnoses to UCMS samples (thesis Table 6.4, Fig. 6.5).

=============================  ==========================================================
black box                      UCMS
=============================  ==========================================================
the robot                      top Monitored Entity (+ Specification)
node (observer resource)       Monitored Entity (+ Specification)
observer x quantity            Monitored Characteristic (+ Specification: unit,
                               descriptor, publishing interval)
bounds of the observer states  Threshold (+ Specification), see ``describe.py``
failed observation             Threshold Exceedence Event (at the onset of a failure)
diagnosis                      Failure Event per component of the best candidate
=============================  ==========================================================

A resource belongs to its node; a topic resource to its owner from ``owners`` (topic ->
node), else to its only publisher, else to an entity named after the topic; a network
interface to ``iface:<name>``; an observation without a resource to the robot. An observer
reporting several quantities (``cpu`` and ``memory``) gives one characteristic per quantity;
one reporting none (``activated``, ``timeout``) gives a ``code`` characteristic whose value is
the observation code (0 OK, negative faulty) with a MIN threshold of 0.

The mapper is pure: it returns the samples to write and keeps the state needed to decide
what changed. Time is the observations' time.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from blackbox.health.describe import ObserverDescription, ThresholdSpec, unit_of
from blackbox.health.extension import (
    C_Characteristic_Extension,
    C_Entity_Description,
    C_Event_Extension,
    C_Parameter,
    T_EventKind,
)
from blackbox.health.identity import EventLedger
from blackbox.health.ids import SourceIds
from blackbox.health.status import (
    FAILING,
    CharacteristicStatus,
    Health,
    Hysteresis,
    entity_health,
    robot_health,
)
from blackbox.health.types import (
    C_Failure_Event,
    C_Monitored_Characteristic,
    C_Monitored_Characteristic_Specification,
    C_Monitored_Entity,
    C_Monitored_Entity_Specification,
    C_Threshold,
    C_Threshold_Exceedence_Event,
    C_Threshold_Specification,
    T_HealthStatus,
    T_IdentifierType,
    T_ThresholdType,
    datetime_of,
)
from blackbox.model import Code, Diagnosis, Observation, Resource


@dataclass(frozen=True, slots=True)
class FailureActions:
    """What the operator is told with a failure event of one entity (from configuration)."""

    consequence: str = ""
    operator_action: str = ""
    maintenance_action: str = ""
    documentation_uri: str = ""


@dataclass(slots=True)
class _Characteristic:
    ident: T_IdentifierType
    entity: str
    quantity: str
    thresholds: list[tuple[ThresholdSpec, T_IdentifierType]]
    active_events: list[T_IdentifierType] = field(default_factory=list)


@dataclass(slots=True)
class _Key:
    """Everything kept for one observer on one resource."""

    entity: str
    status: CharacteristicStatus
    characteristics: dict[str, _Characteristic] = field(default_factory=dict)
    faulty: bool = False
    states: tuple[str, ...] | None = None
    description: ObserverDescription | None = None


@dataclass(slots=True)
class _Entity:
    name: str
    ident: T_IdentifierType
    kind: str
    keys: list[tuple[str, Resource]] = field(default_factory=list)
    characteristics: list[T_IdentifierType] = field(default_factory=list)
    failures: list[T_IdentifierType] = field(default_factory=list)
    health: Health = Health.UNKNOWN
    bit_in_progress: bool = False


def event_key(observer: str, resource: Resource) -> str:
    """The key of an observer's events on a resource in the :class:`EventLedger`."""
    return f"{observer}|{resource_key(resource)}"


def resource_key(resource: Resource) -> str:
    return json.dumps(resource.to_dict(), sort_keys=True, separators=(",", ":"))


def _primary(resource: Resource) -> str | None:
    return resource.node or resource.topic or resource.interface


class HealthMapper:
    """Keeps one robot's UCMS state and says which samples each record changes."""

    def __init__(
        self,
        robot_id: str,
        *,
        descriptions: Iterable[ObserverDescription] = (),
        owners: Mapping[str, str] | None = None,
        failure_actions: Mapping[str, FailureActions] | None = None,
        hysteresis: Hysteresis | None = None,
        logging_interval: float | None = None,
        ledger: EventLedger | None = None,
    ) -> None:
        self.robot_id = robot_id
        self.ids = SourceIds(robot_id)
        self.ledger = ledger or EventLedger()
        """Gives every published event its ``<boot>-<sequence>`` identity; shared with the
        recorder so a logged event carries the identity it was published with."""
        self.owners = dict(owners or {})
        self.failure_actions = dict(failure_actions or {})
        self.rules = hysteresis or Hysteresis()
        self.logging_interval = logging_interval
        self._described: dict[tuple[str, str], ObserverDescription] = {}
        self._described_loose: dict[tuple[str, str], ObserverDescription] = {}
        for d in descriptions:
            self._described[(d.observer, resource_key(d.resource))] = d
            primary = _primary(d.resource)
            if primary:
                self._described_loose.setdefault((d.observer, primary), d)
        self._keys: dict[tuple[str, Resource], _Key] = {}
        self._entities: dict[str, _Entity] = {}
        self._diagnosed: frozenset[str] = frozenset()
        self._robot: _Entity | None = None

    # ---- lookups ----------------------------------------------------------------------------

    def entity_of(self, resource: Resource) -> str:
        return self._entity_and_kind(resource)[0]

    def _entity_and_kind(self, resource: Resource) -> tuple[str, str]:
        if resource.node:
            return resource.node, "node"
        if resource.topic:
            if resource.topic in self.owners:
                return self.owners[resource.topic], "node"
            if len(resource.publishers) == 1:
                return resource.publishers[0], "node"
            return resource.topic, "topic"
        if resource.interface:
            return f"iface:{resource.interface}", "interface"
        return "", "robot"

    def describe(self, observer: str, resource: Resource) -> ObserverDescription | None:
        found = self._described.get((observer, resource_key(resource)))
        if found is None and _primary(resource):
            found = self._described_loose.get((observer, _primary(resource) or ""))
        return found

    def entities(self) -> dict[str, Health]:
        return {name: e.health for name, e in self._entities.items()}

    # ---- building blocks ----------------------------------------------------------------------

    def robot(self, now: float, out: list[Any]) -> _Entity:
        """The robot itself, created (with its samples appended to ``out``) on first use."""
        if self._robot is None:
            self._robot = self._entity("", now, out, "robot")
        return self._robot

    def _entity(self, name: str, now: float, out: list[Any], kind: str = "node") -> _Entity:
        entity = self._entities.get(name)
        if entity is not None:
            return entity
        if name and self._robot is None:
            self.robot(now, out)
        entity = _Entity(name, self.ids.of("entity", name), kind)
        self._entities[name] = entity
        actions = self.failure_actions.get(name) or self.failure_actions.get("*")
        t = datetime_of(now)
        out.append(C_Monitored_Entity_Specification(
            A_sourceID=self.ids.of("entity_spec", name),
            A_timeOfDataGeneration=t,
            A_failureStandardFaultCodeSupported=True,
            A_failureProprietaryFaultCodeSupported=True,
            A_failureDescriptionSupported=True,
            A_failureCauseDescriptionSupported=True,
            A_failureOperationalConsequenceDescriptionSupported=bool(actions
                                                                     and actions.consequence),
            A_failureOperatorActionDescriptionSupported=bool(actions and actions.operator_action),
            A_failureMaintenanceActionDescriptionSupported=bool(actions
                                                                and actions.maintenance_action),
            A_failureComplementaryInformationSupported=True,
            A_failureDocumentationURISupported=bool(actions and actions.documentation_uri),
            A_installationDateTime=t,
            A_specifiedMonitoredEntities_sourceID=[entity.ident],
        ))
        out.append(C_Entity_Description(
            A_sourceID=entity.ident, A_timeOfDataGeneration=t, A_robotId=self.robot_id,
            A_name=name or self.robot_id, A_kind=kind,
            A_parent_sourceID=self.ids.robot() if name else T_IdentifierType(0, 0)))
        out.append(self._entity_sample(entity, now))
        return entity

    def _entity_sample(self, entity: _Entity, now: float) -> C_Monitored_Entity:
        return C_Monitored_Entity(
            A_sourceID=entity.ident,
            A_timeOfDataGeneration=datetime_of(now),
            A_healthStatus=T_HealthStatus(int(entity.health)),
            A_bitInProgress=entity.bit_in_progress,
            A_failureEvents_sourceID=list(entity.failures),
            A_specification_sourceID=self.ids.of("entity_spec", entity.name),
            A_monitoredCharacteristics_sourceID=list(entity.characteristics),
        )

    def _key(self, obs: Observation, now: float, out: list[Any]) -> _Key:
        k = obs.key()
        state = self._keys.get(k)
        if state is not None:
            return state
        description = self.describe(obs.observer, obs.resource)
        name, kind = self._entity_and_kind(obs.resource)
        state = _Key(name, CharacteristicStatus(self.rules, description.interval
                                                if description else None),
                     description=description)
        self._keys[k] = state
        entity = self._entity(name, now, out, kind)
        entity.keys.append(k)
        quantities = list(description.quantities) if description else []
        for q in obs.values:
            if q not in quantities:
                quantities.append(q)
        if not quantities:
            quantities = ["code"]
        for q in quantities:
            self._characteristic(obs, state, q, now, out)
        return state

    def _characteristic(self, obs: Observation, key: _Key, quantity: str, now: float,
                        out: list[Any]) -> _Characteristic:
        rkey = resource_key(obs.resource)
        ident = self.ids.of("characteristic", obs.observer, rkey, quantity)
        spec_id = self.ids.of("characteristic_spec", obs.observer, rkey, quantity)
        d = key.description
        thresholds = [t for t in (d.thresholds if d else ()) if t.quantity == quantity]
        if not thresholds and quantity == "code":
            thresholds = [ThresholdSpec("code", "min", 0.0)]
        t = datetime_of(now)
        th_ids: list[tuple[ThresholdSpec, T_IdentifierType]] = []
        for th in thresholds:
            th_id = self.ids.of("threshold", obs.observer, rkey, quantity, th.type)
            th_spec = self.ids.of("threshold_spec", obs.observer, rkey, quantity, th.type)
            th_ids.append((th, th_id))
            out.append(C_Threshold_Specification(A_sourceID=th_spec, A_timeOfDataGeneration=t,
                                                 A_specifiedThresholds_sourceID=[th_id]))
            out.append(C_Threshold(
                A_sourceID=th_id, A_timeOfDataGeneration=t, A_name=th.name, A_value=th.value,
                A_type=(T_ThresholdType.L_ThresholdType_MIN if th.type == "min"
                        else T_ThresholdType.L_ThresholdType_MAX),
                A_concernedCharacteristic_sourceID=ident, A_specification_sourceID=th_spec))
        interval = d.interval if d and d.interval else None
        name = f"{obs.observer} {obs.resource.label()} {quantity}"
        out.append(C_Monitored_Characteristic_Specification(
            A_sourceID=spec_id, A_timeOfDataGeneration=t, A_unit=unit_of(obs.observer, quantity),
            A_descriptor=name,
            A_publishingIntervalInSeconds=max(1, round(interval)) if interval else 0,
            A_specifiedCharacteristics_sourceID=[ident],
            A_thresholds_sourceID=[i for _, i in th_ids]))
        out.append(C_Characteristic_Extension(
            A_sourceID=ident, A_timeOfDataGeneration=t, A_robotId=self.robot_id, A_name=name,
            A_observer=obs.observer, A_resource=obs.resource.label(), A_quantity=quantity,
            A_expectedNoise=float(d.expected_noise.get(quantity, math.nan)) if d else math.nan,
            A_filterType=d.filter_type if d else "",
            A_filterParameters=[C_Parameter(k, float(v))
                                for k, v in (d.filter_parameters.items() if d else ())],
            A_periodicLoggingIntervalInSeconds=float(self.logging_interval or 0.0),
            A_evaluationIntervalInSeconds=float(interval or 0.0),
            A_states=list(d.states) if d else []))
        c = _Characteristic(ident, key.entity, quantity, th_ids)
        key.characteristics[quantity] = c
        entity = self._entities[key.entity]
        entity.characteristics.append(ident)
        out.append(self._entity_sample(entity, now))
        return c

    def _value(self, obs: Observation, quantity: str) -> float | None:
        if quantity == "code" and quantity not in obs.values:
            return float(int(obs.code))
        v = obs.values.get(quantity)
        return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None

    # ---- records in --------------------------------------------------------------------------

    def start(self, now: float) -> list[Any]:
        """The robot entity's first samples (UNKNOWN until something is observed)."""
        out: list[Any] = []
        self.robot(now, out)
        return out

    def observations(self, now: float, observations: Sequence[Observation]) -> list[Any]:
        out: list[Any] = []
        touched: set[str] = set()
        for obs in observations:
            key = self._key(obs, now, out)
            t = datetime_of(obs.time)
            for quantity, c in key.characteristics.items():
                value = self._value(obs, quantity)
                if value is None or not math.isfinite(value):
                    continue
                out.append(C_Monitored_Characteristic(
                    A_sourceID=c.ident, A_timeOfDataGeneration=t, A_value=value,
                    A_monitoredEntity_sourceID=self._entities[key.entity].ident,
                    A_thresholdExceedenceEvents_sourceID=list(c.active_events),
                    A_specification_sourceID=self.ids.of(
                        "characteristic_spec", obs.observer, resource_key(obs.resource),
                        quantity)))
            available = obs.code != Code.NOT_AVAILABLE
            faulty = obs.faulty and available
            states = tuple(s.name for s in obs.states)
            if faulty and not key.faulty:
                out.extend(self._exceedence(obs, key, T_EventKind.L_EventKind_FAULT, states))
            elif (not faulty and available and key.states is not None and states
                  and states != key.states and not key.faulty):
                out.extend(self._exceedence(obs, key, T_EventKind.L_EventKind_STATE_CHANGE,
                                            states))
            if not faulty and key.faulty:
                for c in key.characteristics.values():
                    c.active_events.clear()
            if available:
                key.faulty = faulty
                if not faulty and states:
                    key.states = states
            if key.status.update(obs.time, faulty, available):
                touched.add(key.entity)
        out.extend(self._refresh(now, touched))
        return out

    def _exceedence(self, obs: Observation, key: _Key, kind: T_EventKind,
                    states: tuple[str, ...]) -> list[Any]:
        chosen: tuple[_Characteristic, float, T_IdentifierType] | None = None
        for q, c in key.characteristics.items():
            value = self._value(obs, q)
            if value is None:
                continue
            for th, th_id in c.thresholds:
                if th.exceeded_by(value):
                    chosen = (c, value, th_id)
                    break
            if chosen is not None:
                break
        if chosen is None:
            c = next(iter(key.characteristics.values()))
            value = self._value(obs, c.quantity)
            chosen = (c, value if value is not None else math.nan, T_IdentifierType(0, 0))
        c, value, th_id = chosen
        ident = self.ids.of("exceedence", str(c.ident.A_instanceId), f"{obs.time:.9f}",
                            str(kind.value))
        event_id = self.ledger.assign(
            "exceedance" if kind == T_EventKind.L_EventKind_FAULT else "state_change",
            event_key(obs.observer, obs.resource), obs.time)
        c.active_events.append(ident)
        t = datetime_of(obs.time)
        return [
            C_Threshold_Exceedence_Event(
                A_sourceID=ident, A_timeOfDataGeneration=t, A_eventOccurrenceDate=t,
                A_measuredValue=value, A_exceededThreshold_sourceID=th_id,
                A_concernedCharacteristic_sourceID=c.ident),
            C_Event_Extension(
                A_sourceID=ident, A_timeOfDataGeneration=t, A_kind=kind, A_code=int(obs.code),
                A_codeName=obs.code.name, A_fromStates=list(key.states or ()),
                A_toStates=list(states), A_message=obs.message, A_eventId=str(event_id)),
        ]

    def diagnosis(self, diagnosis: Diagnosis) -> list[Any]:
        out: list[Any] = []
        best = diagnosis.candidates[0] if diagnosis.candidates else frozenset()
        names = {self.owners.get(c, c) for c in best}
        new = names - self._diagnosed
        gone = self._diagnosed - names
        self._diagnosed = frozenset(names)
        for name in sorted(gone):
            entity = self._entity(name, diagnosis.time, out)
            entity.failures.clear()
            out.append(self._rectification(diagnosis.time, entity))
        for name in sorted(new):
            entity = self._entity(name, diagnosis.time, out)
            failure = self._failure(diagnosis, entity)
            # The identity first: a station that gets the event before its extension waits.
            out.append(C_Event_Extension(
                A_sourceID=failure.A_sourceID, A_timeOfDataGeneration=failure.A_eventOccurrenceDate,
                A_kind=T_EventKind.L_EventKind_FAILURE, A_code=int(failure.A_standardFaultCode),
                A_codeName=failure.A_proprietaryFaultCode, A_message=failure.A_failureDescription,
                A_eventId=str(self.ledger.assign("failure", name, diagnosis.time)),
                A_entity_sourceID=entity.ident))
            out.append(failure)
        out.extend(self._refresh(diagnosis.time, (), force=new | gone))
        return out

    def _rectification(self, time: float, entity: _Entity) -> C_Event_Extension:
        """A component left the diagnosis: UCMS has no event for it, the extension does."""
        t = datetime_of(time)
        return C_Event_Extension(
            A_sourceID=self.ids.of("rectification", entity.name, f"{time:.9f}"),
            A_timeOfDataGeneration=t, A_kind=T_EventKind.L_EventKind_RECTIFICATION,
            A_message=f"{entity.name} is no longer diagnosed faulty",
            A_eventId=str(self.ledger.assign("rectification", entity.name, time)),
            A_entity_sourceID=entity.ident)

    def _failure(self, diagnosis: Diagnosis, entity: _Entity) -> C_Failure_Event:
        ident = self.ids.of("failure", entity.name, f"{diagnosis.time:.9f}")
        entity.failures.append(ident)
        mine = [o for o in diagnosis.failed if self.entity_of(o.resource) == entity.name]
        codes = sorted({o.code for o in (mine or diagnosis.failed)})
        actions = (self.failure_actions.get(entity.name) or self.failure_actions.get("*")
                   or FailureActions())
        others = len(diagnosis.candidates) - 1
        description = f"{entity.name or self.robot_id} diagnosed faulty"
        if others > 0:
            description += f" (best of {len(diagnosis.candidates)} candidate explanations)"
        cause = diagnosis.explanation or "; ".join(
            f"{o.observer} {o.resource.label()}: {o.code.name} {o.message}".strip()
            for o in diagnosis.failed)
        info = "candidates: " + " | ".join("{" + ", ".join(sorted(c)) + "}"
                                           for c in diagnosis.candidates)
        if not diagnosis.complete:
            info += " (search incomplete)"
        info += f"; engine {diagnosis.engine}"
        if diagnosis.agreement:
            info += f" ({diagnosis.agreement})"
        t = datetime_of(diagnosis.time)
        return C_Failure_Event(
            A_sourceID=ident, A_timeOfDataGeneration=t, A_eventOccurrenceDate=t,
            A_standardFaultCode=float(int(codes[0])) if codes else float(Code.GENERAL_ERROR),
            A_proprietaryFaultCode=",".join(c.name for c in codes),
            A_failureDescription=description, A_causeDescription=cause,
            A_operationalConsequenceDescription=actions.consequence,
            A_operatorActionDescription=actions.operator_action,
            A_maintenanceActionDescription=actions.maintenance_action,
            A_complementaryInformation=info, A_eventDocumentationURI=actions.documentation_uri,
            A_monitoredEntity_sourceID=entity.ident)

    def expire(self, now: float) -> list[Any]:
        """Characteristics silent for too long become unknown; returns changed entities."""
        touched = {k.entity for k in self._keys.values() if k.status.expire(now)}
        return self._refresh(now, touched)

    def set_bit_in_progress(self, now: float, running: bool) -> list[Any]:
        out = []
        for entity in self._entities.values():
            entity.bit_in_progress = running
            out.append(self._entity_sample(entity, now))
        return out

    def _refresh(self, now: float, touched: Iterable[str], force: Iterable[str] = ()) -> list[Any]:
        force = set(force)
        touched = set(touched) | force
        out: list[Any] = []
        for name in touched:
            entity = self._entities.get(name)
            if entity is None or name == "":
                continue
            states = [self._keys[k].status.state for k in entity.keys]
            health = entity_health(states, name in self._diagnosed)
            if health != entity.health or name in force:
                entity.health = health
                out.append(self._entity_sample(entity, now))
        robot = self.robot(now, out)
        own = [self._keys[k].status.state for k in robot.keys]
        children = [e.health for n, e in self._entities.items() if n != ""]
        if own:
            children.append(entity_health(own, False))
        health = robot_health(children)
        failures = [f for e in self._entities.values() if e.name for f in e.failures]
        if health != robot.health or failures != robot.failures or "" in touched:
            robot.health = health
            robot.failures = failures
            out.append(self._entity_sample(robot, now))
        return out

    def failing(self) -> list[str]:
        return [name for name, e in self._entities.items()
                if any(self._keys[k].status.state == FAILING for k in e.keys)]
