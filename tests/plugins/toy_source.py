"""A throw-away source in one file: scheme ``toy``, a node publishing ``/toy`` at 10 Hz.

It declares what it can do (a simulated clock, nothing else), so the black box lets it run
faster than real time and refuses to inject faults into it, without knowing its name.
"""

from __future__ import annotations

from blackbox.events import (
    Event,
    GraphSnapshot,
    Interest,
    MessageArrival,
    NodeInfo,
    TopicInfo,
    TopicSchema,
)
from blackbox.sources.base import SOURCES, Capabilities, SourceKind, SourceOptions

TOY_CAPABILITIES = Capabilities(simulated_clock=True)
PERIOD = 0.1


class ToySource:
    capabilities = TOY_CAPABILITIES

    def __init__(self, spec: str) -> None:
        self.name = spec
        self._now = 0.0
        self._next = PERIOD

    def start(self, interest: Interest) -> None:
        return None

    def now(self) -> float:
        return self._now

    def poll(self, until: float) -> list[Event]:
        events: list[Event] = []
        if self._now == 0.0:
            events.append(GraphSnapshot(0.0, {"/toy_node": NodeInfo("/toy_node", True)},
                                        {"/toy": TopicInfo("/toy", "std_msgs/Empty",
                                                           ("/toy_node",))}))
        while self._next <= until:
            events.append(MessageArrival(self._next, "/toy", "/toy_node", 0, value=None))
            self._next = round(self._next + PERIOD, 9)
        self._now = max(self._now, until)
        return events

    def schema(self, topic: str) -> TopicSchema | None:
        return None

    def close(self) -> None:
        return None


def open_toy(spec: str, options: SourceOptions) -> ToySource:
    return ToySource(spec)


SOURCES.add("toy", SourceKind("toy", open_toy, TOY_CAPABILITIES, "toy:"))
