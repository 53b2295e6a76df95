"""The QoS of a ROS 2 endpoint as discovered over DDS, and the classic incompatibilities.

A publisher and a subscriber on the same topic whose QoS do not match never talk to each
other, and nothing fails loudly: the subscriber simply receives nothing. That is why the
source reports every incompatible pair it sees (:func:`incompatibilities`), by the DDS
request/offered rules for the policies ROS 2 exposes: reliability, durability, deadline,
liveliness (kind and lease duration) and ownership.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from cyclonedds.qos import Policy, Qos

__all__ = ["EndpointQos", "incompatibilities"]

_INFINITE = 0x7FFFFFFFFFFFFFFF
_DURABILITY_RANK = {"volatile": 0, "transient_local": 1, "transient": 2, "persistent": 3}
_LIVELINESS_RANK = {"automatic": 0, "manual_by_participant": 1, "manual_by_topic": 2}
_NAMES = {"BestEffort": "best_effort", "Reliable": "reliable", "Volatile": "volatile",
          "TransientLocal": "transient_local", "Transient": "transient",
          "Persistent": "persistent", "Automatic": "automatic",
          "ManualByParticipant": "manual_by_participant", "ManualByTopic": "manual_by_topic",
          "Shared": "shared", "Exclusive": "exclusive", "KeepLast": "keep_last",
          "KeepAll": "keep_all"}


def _kind(policy: Any, default: str) -> str:
    if policy is None:
        return default
    return _NAMES.get(type(policy).__name__.rsplit(".", 1)[-1], default)


def _ns(value: Any) -> int:
    return _INFINITE if value is None or value < 0 or value >= _INFINITE else int(value)


@dataclass(frozen=True, slots=True)
class EndpointQos:
    """The ROS-visible QoS of one endpoint; durations in nanoseconds (``_INFINITE`` = none).

    Defaults are the DDS defaults of a policy the endpoint did not announce (a reader's
    reliability defaults to best effort, a writer's to reliable).
    """

    reliability: str
    durability: str = "volatile"
    history: str = "keep_last"
    depth: int = 1
    deadline_ns: int = _INFINITE
    liveliness: str = "automatic"
    lease_ns: int = _INFINITE
    ownership: str = "shared"

    @classmethod
    def from_dds(cls, qos: Qos | None, writer: bool) -> EndpointQos:
        def get(policy: Any) -> Any:
            return qos[policy] if qos is not None else None

        history = get(Policy.History)
        deadline = get(Policy.Deadline)
        liveliness = get(Policy.Liveliness)
        return cls(
            reliability=_kind(get(Policy.Reliability), "reliable" if writer else "best_effort"),
            durability=_kind(get(Policy.Durability), "volatile"),
            history=_kind(history, "keep_last"),
            depth=int(getattr(history, "depth", 1) or 1),
            deadline_ns=_ns(getattr(deadline, "deadline", None)),
            liveliness=_kind(liveliness, "automatic"),
            lease_ns=_ns(getattr(liveliness, "lease_duration", None)),
            ownership=_kind(get(Policy.Ownership), "shared"),
        )

    def describe(self) -> str:
        parts = [self.reliability, self.durability,
                 f"keep_last({self.depth})" if self.history == "keep_last" else "keep_all"]
        if self.deadline_ns != _INFINITE:
            parts.append(f"deadline {self.deadline_ns / 1e9:g} s")
        if self.liveliness != "automatic" or self.lease_ns != _INFINITE:
            lease = "" if self.lease_ns == _INFINITE else f" {self.lease_ns / 1e9:g} s"
            parts.append(f"liveliness {self.liveliness}{lease}")
        if self.ownership != "shared":
            parts.append(f"ownership {self.ownership}")
        return ", ".join(parts)


def incompatibilities(offered: EndpointQos, requested: EndpointQos) -> list[str]:
    """Why a writer offering ``offered`` cannot serve a reader requesting ``requested``
    (empty when they match)."""
    why: list[str] = []
    if offered.reliability == "best_effort" and requested.reliability == "reliable":
        why.append("reliability: the publisher is best_effort, the subscriber wants reliable")
    if _DURABILITY_RANK.get(offered.durability, 0) < _DURABILITY_RANK.get(
            requested.durability, 0):
        why.append(f"durability: the publisher is {offered.durability}, the subscriber wants "
                   f"{requested.durability}")
    if offered.deadline_ns > requested.deadline_ns:
        why.append("deadline: the publisher promises a longer deadline than the subscriber "
                   "requests")
    if (_LIVELINESS_RANK.get(offered.liveliness, 0) < _LIVELINESS_RANK.get(
            requested.liveliness, 0) or offered.lease_ns > requested.lease_ns):
        why.append("liveliness: the publisher's kind or lease duration is weaker than the "
                   "subscriber requests")
    if offered.ownership != requested.ownership:
        why.append(f"ownership: {offered.ownership} publisher, {requested.ownership} "
                   "subscriber")
    return why
