"""Where the pipeline's records go: the recorder, DDS, JSON lines files, the live view.

A sink receives records in time order from the pipeline's single thread. Sinks must not
block for long; slow work (disk, network) belongs behind a sink's own queue. A sink that
sets ``wants_messages`` also receives every raw message arrival (the recorder's snapshot
ring buffer); all others never pay for that.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from blackbox.events import MessageArrival
from blackbox.model import BlackBoxEvent, Diagnosis, Observation


class Sink(Protocol):
    wants_messages: bool

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None: ...

    def on_diagnosis(self, diagnosis: Diagnosis) -> None: ...

    def on_event(self, event: BlackBoxEvent) -> None: ...

    def on_message(self, msg: MessageArrival) -> None: ...

    def close(self) -> None: ...


class SinkBase:
    """No-op defaults, so a sink implements only what it consumes."""

    wants_messages: bool = False

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        return None

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        return None

    def on_event(self, event: BlackBoxEvent) -> None:
        return None

    def on_message(self, msg: MessageArrival) -> None:
        return None

    def close(self) -> None:
        return None


class Collector(SinkBase):
    """Keeps every observation and diagnosis in memory, in the order they came: what a
    campaign or an experiment scores once its run is over."""

    def __init__(self) -> None:
        self.observations: list[Observation] = []
        self.diagnoses: list[Diagnosis] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self.observations.extend(observations)

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        self.diagnoses.append(diagnosis)
