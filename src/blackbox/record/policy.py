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

from blackbox.model import Observation, Resource

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
    rule: PolicyRule
    channel: tuple[str | None, str | None, str]
    code: int | None = None
    states: tuple[int, ...] = ()
    logged: float = float("-inf")
    boost_until: float = float("-inf")


class PolicyTracker:
    """Applies a :class:`LoggingPolicy` to a stream of observations, one per call."""

    def __init__(self, policy: LoggingPolicy) -> None:
        self.policy = policy
        self._tracks: dict[tuple[str, Resource], _Track] = {}

    def _track(self, obs: Observation) -> _Track:
        key = obs.key()
        track = self._tracks.get(key)
        if track is None:
            entity = entity_of(obs.resource)
            resource = json.dumps(obs.resource.to_dict(), sort_keys=True, separators=(",", ":"))
            track = _Track(self.policy.rule_for(entity, obs.observer),
                           (entity, obs.observer, resource))
            self._tracks[key] = track
        return track

    def decide(self, obs: Observation) -> Decision | None:
        track = self._track(obs)
        rule = track.rule
        code = int(obs.code)
        states = tuple(s.number for s in obs.states)
        t = obs.time
        if code != track.code or states != track.states:
            was_faulty = track.code is not None and track.code < 0
            started = code < 0 and not was_faulty
            boost = rule.on_fault
            if started and boost is not None:
                track.boost_until = t + boost.duration
            track.code, track.states, track.logged = code, states, t
            kind = "exceedance" if code < 0 else "observation"
            return Decision(kind, track.channel, started,
                            started and boost is not None and boost.snapshot)
        interval = self._interval(track, obs)
        if interval is not None and t - track.logged >= interval - _EPS:
            track.logged = t
            return Decision("sample", track.channel, False, False)
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
