"""The black box watching itself.

Its own parts (the recorder, the DDS link) report their health as ordinary observations,
so a full disk or a dead link shows up in the live view, the log, the diagnosis and the
health messages exactly like a fault of the robot.
"""

from __future__ import annotations

from collections.abc import Callable

from blackbox.events import Interest
from blackbox.model import Observation, Resource
from blackbox.observe.base import ObserverBase


class ProbeObserver(ObserverBase):
    """Evaluates a health probe of one of the black box's own components."""

    def __init__(self, type_name: str, resource: Resource,
                 probe: Callable[[float], Observation], interval: float = 1.0) -> None:
        self.type_name = type_name  # type: ignore[misc]
        self.resource = resource
        self.probe = probe
        self.interval = interval

    def interest(self) -> Interest:
        return Interest()

    def evaluate(self, now: float) -> list[Observation]:
        return [self.probe(now)]

    def describe(self) -> str:
        return f"{self.type_name} {self.resource.label()}: the black box's own health"
