"""What of the observation stream is worth keeping: the HUMS logging techniques.

Observers evaluate every second or faster, but a healthy characteristic says the same
thing every time. The recorder therefore always logs *changes* (of code or of fitting
states) and otherwise only samples: *periodically* (``interval``), at another interval
while the characteristic is in given states (*state-driven*), and faster for a while
after it turns faulty (*event-driven*, which also asks for a snapshot).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from typing import Any

from blackbox.model import Observation, Resource, State

_EPS = 1e-6


@dataclass(frozen=True, slots=True)
class FaultBoost:
    """Event-driven logging: sample every ``interval`` s for ``duration`` s after a fault."""

    interval: float = 1.0
    duration: float = 30.0
    snapshot: bool = True


@dataclass(frozen=True, slots=True)
class PolicyRule:
    """Logging of the characteristics whose entity and observer type match the globs.

    ``interval`` ``None`` means no periodic samples (changes are still logged).
    ``states`` maps a state name or number (as text) to the sampling interval while that
    state fits.
    """

    entity: str = "*"
    characteristic: str = "*"
    interval: float | None = 60.0
    on_fault: FaultBoost | None = field(default_factory=FaultBoost)
    states: Mapping[str, float] = field(default_factory=dict)

    def matches(self, entity: str, characteristic: str) -> bool:
        return fnmatchcase(entity, self.entity) and fnmatchcase(characteristic, self.characteristic)


@dataclass(frozen=True, slots=True)
class LoggingPolicy:
    """Rules tried in order; the first match applies, else ``default``."""

    rules: tuple[PolicyRule, ...] = ()
    default: PolicyRule = field(default_factory=PolicyRule)

    def rule_for(self, entity: str, characteristic: str) -> PolicyRule:
        for rule in self.rules:
            if rule.matches(entity, characteristic):
                return rule
        return self.default


def entity_of(resource: Resource) -> str:
    return resource.node or resource.topic or resource.interface or "robot"


@dataclass(frozen=True, slots=True)
class Decision:
    """Log ``observation`` as ``kind``; ``fault_started`` when it just turned faulty."""

    kind: str
    channel: tuple[str | None, str | None, str]
    fault_started: bool
    snapshot: bool


@dataclass(slots=True)
class _Track:
    """One characteristic's logging state, with its four possible decisions made once."""

    rule: PolicyRule
    resource: Resource
    channel: tuple[str | None, str | None, str]
    change: Decision
    fault: Decision
    fault_started: Decision
    sample: Decision
    fixed_interval: bool
    code: int | None = None
    states: tuple[State, ...] | None = None
    numbers: tuple[int, ...] = ()
    logged: float = float("-inf")
    boost_until: float = float("-inf")


class PolicyTracker:
    """Applies a :class:`LoggingPolicy` to a stream of observations, one per call.

    Runs on the pipeline thread for every observation, so a characteristic's rule,
    channel and decisions are looked up once and kept in its track.
    """

    def __init__(self, policy: LoggingPolicy) -> None:
        self.policy = policy
        self._tracks: dict[tuple[str, Resource], _Track] = {}
        # The same tracks by the identity of the Resource they were made with: an observer
        # keeps its resource, and hashing a frozen dataclass runs Python code every time.
        # The track holds that object, so its id cannot be reused while the entry exists.
        self._by_identity: dict[tuple[str, int], _Track] = {}

    def _new_track(self, obs: Observation) -> _Track:
        entity = entity_of(obs.resource)
        resource = json.dumps(obs.resource.to_dict(), sort_keys=True, separators=(",", ":"))
        channel = (entity, obs.observer, resource)
        rule = self.policy.rule_for(entity, obs.observer)
        boost = rule.on_fault
        track = _Track(rule, obs.resource, channel,
                       change=Decision("observation", channel, False, False),
                       fault=Decision("exceedance", channel, False, False),
                       fault_started=Decision("exceedance", channel, True,
                                              boost is not None and boost.snapshot),
                       sample=Decision("sample", channel, False, False),
                       fixed_interval=not rule.states)
        self._tracks[(obs.observer, obs.resource)] = track
        self._by_identity[(obs.observer, id(obs.resource))] = track
        return track

    def decide(self, obs: Observation) -> Decision | None:
        track = self._by_identity.get((obs.observer, id(obs.resource)))
        if track is None or track.resource is not obs.resource:
            track = self._tracks.get((obs.observer, obs.resource))
            if track is None:
                track = self._new_track(obs)
        code = int(obs.code)
        t = obs.time
        states = obs.states
        changed = code != track.code
        if states != track.states:  # equal tuples of the same State objects compare fast
            numbers = tuple([s.number for s in states])
            changed = changed or numbers != track.numbers
            track.states, track.numbers = states, numbers
        if changed:
            was_faulty = track.code is not None and track.code < 0
            track.code, track.logged = code, t
            if code >= 0:
                return track.change
            if was_faulty:
                return track.fault
            boost = track.rule.on_fault
            if boost is not None:
                track.boost_until = t + boost.duration
            return track.fault_started
        if track.fixed_interval and t >= track.boost_until:
            interval = track.rule.interval
        else:
            interval = self._interval(track, obs)
        if interval is not None and t - track.logged >= interval - _EPS:
            track.logged = t
            return track.sample
        return None

    @staticmethod
    def _interval(track: _Track, obs: Observation) -> float | None:
        rule = track.rule
        candidates: list[float] = []
        if rule.interval is not None:
            candidates.append(rule.interval)
        if rule.on_fault is not None and obs.time < track.boost_until:
            candidates.append(rule.on_fault.interval)
        if rule.states:
            for s in obs.states:
                v = rule.states.get(s.name, rule.states.get(str(s.number)))
                if v is not None:
                    candidates.append(v)
        return min(candidates) if candidates else None


def observation_payload(obs: Observation, full: bool) -> dict[str, Any]:
    """Payload of a logged observation; samples leave out what a change already said."""
    payload: dict[str, Any] = {"values": dict(obs.values),
                               "states": [s.number for s in obs.states]}
    if full:
        payload["state_names"] = [s.name for s in obs.states]
        payload["code_name"] = obs.code.name
        if obs.message:
            payload["message"] = obs.message
    return payload

