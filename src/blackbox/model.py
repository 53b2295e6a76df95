"""Records that flow through the black box: observations and diagnoses.

Every stage after the observers speaks in these records, so they are plain frozen
dataclasses with a stable dictionary form (``to_dict``) that the JSON lines output,
the recorder and the DDS mapping all share. See ``docs/observations.md`` for the schema.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any


class Code(IntEnum):
    """Observation result codes of the TU Graz tool; negative means faulty."""

    GENERAL_OK = 0
    GENERAL_ERROR = -1
    NO_STATE_FITS = -2
    NOT_AVAILABLE = -3
    TIMEOUT = -4

    @property
    def faulty(self) -> bool:
        return self < 0


@dataclass(frozen=True, slots=True)
class Resource:
    """What an observation is about, structured so nobody parses strings later.

    ``publishers`` is the publisher group (tug ``callerid``); empty means all publishers
    of the topic. ``topic_b`` is the second topic of a two-topic observer (timing,
    velocity). ``interface`` names a network interface.
    """

    node: str | None = None
    topic: str | None = None
    publishers: tuple[str, ...] = ()
    topic_b: str | None = None
    interface: str | None = None

    def label(self) -> str:
        parts: list[str] = []
        if self.node:
            parts.append(self.node)
        if self.topic:
            t = self.topic if not self.topic_b else f"{self.topic} -> {self.topic_b}"
            parts.append(t + (f" [{','.join(self.publishers)}]" if self.publishers else ""))
        if self.interface:
            parts.append(f"iface {self.interface}")
        return " ".join(parts) or "robot"

    def to_dict(self) -> dict[str, Any]:
        return {
            "node": self.node,
            "topic": self.topic,
            "publishers": list(self.publishers),
            "topic_b": self.topic_b,
            "interface": self.interface,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Resource:
        return cls(
            node=d.get("node"),
            topic=d.get("topic"),
            publishers=tuple(d.get("publishers") or ()),
            topic_b=d.get("topic_b"),
            interface=d.get("interface"),
        )


@dataclass(frozen=True, slots=True)
class State:
    """A numbered, named state of an observed quantity (tug ``state``/``number``)."""

    number: int
    name: str


@dataclass(frozen=True, slots=True)
class Observation:
    """One observer's verdict on one resource at one time.

    ``values`` holds the filtered quantities the verdict was made on (for example
    ``{"period": 0.067, "period_deviation": 0.002}``); ``states`` all states that fit.
    """

    time: float
    observer: str
    resource: Resource
    code: Code
    states: tuple[State, ...] = ()
    values: Mapping[str, float] = field(default_factory=dict)
    message: str = ""

    @property
    def faulty(self) -> bool:
        return self.code < 0

    def key(self) -> tuple[str, Resource]:
        """Identity of the observed characteristic across time."""
        return (self.observer, self.resource)

    def to_dict(self) -> dict[str, Any]:
        return {
            "time": self.time,
            "observer": self.observer,
            "resource": self.resource.to_dict(),
            "code": int(self.code),
            "code_name": self.code.name,
            "faulty": self.faulty,
            "states": [{"number": s.number, "name": s.name} for s in self.states],
            "values": dict(self.values),
            "message": self.message,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Observation:
        return cls(
            time=float(d["time"]),
            observer=str(d["observer"]),
            resource=Resource.from_dict(d["resource"]),
            code=Code(int(d["code"])),
            states=tuple(State(int(s["number"]), str(s["name"])) for s in d.get("states", ())),
            values=dict(d.get("values") or {}),
            message=str(d.get("message", "")),
        )


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """Ranked minimal diagnoses explaining the currently failed observations.

    ``candidates`` is best first; each candidate is a set of component names
    (nodes, topics or hardware behind a driver) assumed abnormal. An empty
    ``candidates`` tuple with no failed observations means all healthy.

    ``engine`` says which method made it (``cbd``, ``sfdd`` or ``hybrid``, see
    docs/diagnosis.md); ``agreement`` is the hybrid's word on whether CBD and SFDD agree
    (empty for a single engine).
    """

    time: float
    candidates: tuple[frozenset[str], ...]
    failed: tuple[Observation, ...] = ()
    explanation: str = ""
    complete: bool = True
    engine: str = "cbd"
    agreement: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "time": self.time,
            "candidates": [sorted(c) for c in self.candidates],
            "failed": [o.to_dict() for o in self.failed],
            "explanation": self.explanation,
            "complete": self.complete,
            "engine": self.engine,
            "agreement": self.agreement,
        }


@dataclass(frozen=True, slots=True)
class BlackBoxEvent:
    """Something that happened to the black box itself (start, stop, source lost, ...)."""

    time: float
    kind: str
    message: str
    component: str = "blackbox"

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "kind": self.kind, "message": self.message,
                "component": self.component}
