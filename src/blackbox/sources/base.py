"""What a robot adapter is: the ``Source`` protocol, its capabilities and its registry.

A source turns a robot (simulated, ROS 1, bag replay, ...) into the time-ordered events of
:mod:`blackbox.events`. Each kind of source is one module that registers a URL scheme in
:data:`SOURCES` with a :class:`SourceKind`, which says what the source can do
(:class:`Capabilities`), so nothing else ever matches a source's name.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

from blackbox.config.node import ConfigError
from blackbox.events import (
    Event,
    Interest,
    TopicSchema,
)
from blackbox.registry import Registry

if TYPE_CHECKING:
    from blackbox.sources.sim.faults import Fault, GroundTruth

__all__ = [
    "SOURCES",
    "Capabilities",
    "GroundTruthSource",
    "RandomFaults",
    "ReplaySource",
    "Source",
    "SourceKind",
    "SourceOptions",
    "source_kind",
]


@dataclass(frozen=True, slots=True)
class Capabilities:
    """What a kind of source can do beyond reporting events.

    ``simulated_clock``: it can run on its own clock, faster than real time.
    ``fault_injection``: it injects faults it is given. ``ground_truth``: it knows the
    faults it injected (see :class:`GroundTruthSource`). ``replay``: it is a recording
    that ends by itself (see :class:`ReplaySource`) and plays in real time at
    ``SourceOptions.rate``. ``snapshot_format``: the format the recorder writes its raw
    messages in (``ros1`` bags or ``mcap``). ``diagnostics_bridge``: the middleware whose
    ``/diagnostics`` ``--publish-diagnostics`` publishes on when watching this source
    (``None``: ROS 2 on ``$ROS_DOMAIN_ID``).
    """

    simulated_clock: bool = False
    fault_injection: bool = False
    ground_truth: bool = False
    replay: bool = False
    snapshot_format: Literal["ros1", "mcap"] = "mcap"
    diagnostics_bridge: Literal["ros1", "ros2"] | None = None


@dataclass(frozen=True, slots=True)
class RandomFaults:
    """A seeded random fault campaign over ``[warmup, horizon)`` (see the simulator)."""

    horizon: float
    kinds: tuple[str, ...] | None = None
    mean_gap: float = 10.0
    warmup: float = 5.0
    min_separation: float = 0.0


FaultPlan = str | Path | RandomFaults | Sequence["Fault"] | None
"""Faults to inject: a fault file, a random campaign or faults; ``None`` for none."""


@dataclass(frozen=True, slots=True)
class SourceOptions:
    """How to open a source. Only a source with the matching capability takes ``faults``
    or ``realtime=False``; ``start_time`` ``None`` means the wall clock in real time, else 0
    (a recording: its first message). Only a ``replay`` source takes a ``rate``: recorded
    seconds per real second in real time (``None``: 1)."""

    realtime: bool = True
    start_time: float | None = None
    rate: float | None = None
    seed: int = 1
    faults: FaultPlan = None


class Source(Protocol):
    """A robot adapter.

    The pipeline calls ``start`` once, then ``poll(until)`` repeatedly with increasing
    times; ``poll`` returns every event with ``time <= until`` in time order. A real-time
    source blocks until the wall clock reaches ``until``; a simulated one computes the
    events at once. Times are seconds on the source's clock (``now()``).
    """

    name: str
    capabilities: Capabilities

    def start(self, interest: Interest) -> None: ...

    def now(self) -> float: ...

    def poll(self, until: float) -> list[Event]: ...

    def schema(self, topic: str) -> TopicSchema | None:
        """The encoding of ``topic``'s raw bytes, once known (``None`` before or if never)."""
        ...

    def close(self) -> None: ...


class GroundTruthSource(Source, Protocol):
    """A source that knows the faults it injected (``capabilities.ground_truth``)."""

    @property
    def ground_truth(self) -> Sequence[GroundTruth]: ...

    def topic_publishers(self) -> Mapping[str, str]:
        """Each topic's publisher node, for scoring observations against the faults."""
        ...


class ReplaySource(Source, Protocol):
    """A recording (``capabilities.replay``): it runs out, and then the run is over."""

    def exhausted(self) -> bool:
        """True once every recorded event has been returned by ``poll``."""
        ...


SourceOpener = Callable[[str, SourceOptions], Source]


@dataclass(frozen=True, slots=True)
class SourceKind:
    """A kind of source: its URL scheme, what it can do and how to open a spec.

    A spec is ``SCHEME`` alone, ``SCHEME:REST`` or ``SCHEME://REST``; ``usage`` lists the
    accepted forms for error messages.
    """

    scheme: str
    open: SourceOpener
    capabilities: Capabilities
    usage: str


SOURCES: Registry[SourceKind] = Registry("source scheme", "blackbox.sources")


def scheme_of(spec: str) -> str:
    return spec.split(":", 1)[0]


def source_kind(spec: str) -> SourceKind:
    """The registered kind of source ``spec`` names, or a ``ConfigError`` for ``--source``."""
    kind = SOURCES.get(scheme_of(spec))
    if kind is None:
        usage = ", ".join(k.usage for _, k in SOURCES.items())
        raise ConfigError(f"unknown source {spec!r}; expected {usage}", "--source")
    return kind
