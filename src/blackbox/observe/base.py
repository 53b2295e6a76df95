"""Contracts of the observation layer: filters, hypothesis checks and observers.

Everything here is pure: no threads, no I/O, no clocks. Time is always passed in, so a
five-minute robot run replays in milliseconds on a simulated clock.

A filter is a streaming statistic in the style of ``river``: ``update(x)`` then ``get()``.
A check decides whether a filtered :class:`Summary` fits a state. An observer turns
source events into :class:`~blackbox.model.Observation` records when ``evaluate(now)``
is called.

New kinds register by type name in the registries below (one module plus one line in
the package ``__init__``); configuration files refer to them by that name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol, TypeVar

from blackbox.model import Observation
from blackbox.sources.base import (
    GraphSnapshot,
    Interest,
    MessageArrival,
    NetworkSample,
    ResourceSample,
)

if TYPE_CHECKING:
    from blackbox.config.node import ConfigNode


@dataclass(frozen=True, slots=True)
class Summary:
    """What a filter says about its window: the filtered value, its deviation, sample count.

    ``deviation`` is ``None`` when undefined (for example a sample standard deviation of a
    single sample).
    """

    value: float
    deviation: float | None
    count: int


class Filter(Protocol):
    """A streaming filter over a window of samples."""

    def update(self, x: float) -> None: ...

    def get(self) -> float | None:
        """The filtered value, ``None`` before the first sample."""
        ...

    def deviation(self) -> float | None: ...

    def count(self) -> int: ...

    def summary(self) -> Summary | None:
        """``None`` before the first sample."""
        ...

    def reset(self) -> None: ...


class Check(Protocol):
    """A hypothesis check on a filtered summary."""

    def test(self, summary: Summary) -> bool: ...

    def describe(self) -> str: ...


class Observer(Protocol):
    """Observes one resource (a node, a topic with a publisher group, a pair of topics, ...).

    ``interval`` is the time between evaluations in seconds (tug ``main_loop_rate`` is its
    inverse). The pipeline feeds events in time order and calls ``evaluate(now)`` every
    ``interval`` seconds; ``evaluate`` returns the observations made at ``now`` (usually one).
    """

    type_name: ClassVar[str]
    interval: float

    def interest(self) -> Interest: ...

    def on_message(self, msg: MessageArrival) -> None: ...

    def on_graph(self, graph: GraphSnapshot) -> None: ...

    def on_resources(self, sample: ResourceSample) -> None: ...

    def on_network(self, sample: NetworkSample) -> None: ...

    def evaluate(self, now: float) -> list[Observation]: ...

    def describe(self) -> str:
        """One human line saying what is observed and how (for ``check-config``)."""
        ...


class ObserverBase:
    """Default no-op event handlers so an observer only writes what it uses."""

    type_name: ClassVar[str] = ""
    interval: float = 1.0

    def on_message(self, msg: MessageArrival) -> None:
        return None

    def on_graph(self, graph: GraphSnapshot) -> None:
        return None

    def on_resources(self, sample: ResourceSample) -> None:
        return None

    def on_network(self, sample: NetworkSample) -> None:
        return None


FilterFactory = Callable[["ConfigNode"], Filter]
CheckFactory = Callable[["ConfigNode"], Check]
ObserverFactory = Callable[["ConfigNode"], Observer]

FILTERS: dict[str, FilterFactory] = {}
VALUE_CHECKS: dict[str, CheckFactory] = {}
OBSERVERS: dict[str, ObserverFactory] = {}

_T = TypeVar("_T")


def register(registry: dict[str, Callable[..., _T]], name: str
             ) -> Callable[[Callable[..., _T]], Callable[..., _T]]:
    """Decorator registering a factory under a configuration type name."""

    def deco(factory: Callable[..., _T]) -> Callable[..., _T]:
        if name in registry:
            raise ValueError(f"{name!r} registered twice")
        registry[name] = factory
        return factory

    return deco
