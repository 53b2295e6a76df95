"""Contracts of the observation layer: filters, hypothesis checks and observers.

Everything here is pure: no threads, no I/O, no clocks. Time is always passed in, so a
five-minute robot run replays in milliseconds on a simulated clock.

A filter is a streaming statistic in the style of ``river``: ``update(x)`` then ``get()``.
A check decides whether a filtered :class:`Summary` fits a state. An observer turns
source events into :class:`~blackbox.model.Observation` records when ``evaluate(now)``
is called.

New kinds register by type name in the registries below, from their own module (see
:mod:`blackbox.registry`); configuration files refer to them by that name. An observer
type registers an :class:`ObserverKind`: besides its factory, the facts the other stages
need about it (quantities and units, the failure mode it judges, fixed thresholds, its
tug_observers form), so nothing else keeps a table keyed by observer type.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import ClassVar, Literal, Protocol, runtime_checkable

from blackbox.config.node import ConfigNode
from blackbox.config.tug import TugForm
from blackbox.events import (
    GraphSnapshot,
    Interest,
    MeasurementGap,
    MessageArrival,
    NetworkSample,
    ResourceSample,
)
from blackbox.model import Code, Observation, Resource
from blackbox.registry import Registry


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

    An observer may also define ``on_batch(batch: ArrivalBatch)`` to take the messages of
    one receive in one call (see :class:`~blackbox.events.ArrivalBatch`; ``hz`` and
    ``timeout`` do); without it the pipeline hands it those messages one by one through
    ``on_message``, so it must behave exactly like that many calls.
    """

    type_name: ClassVar[str]
    interval: float
    resource: Resource

    def interest(self) -> Interest: ...

    def on_message(self, msg: MessageArrival) -> None: ...

    def on_graph(self, graph: GraphSnapshot) -> None: ...

    def on_resources(self, sample: ResourceSample) -> None: ...

    def on_network(self, sample: NetworkSample) -> None: ...

    def on_gap(self, gap: MeasurementGap) -> None:
        """The source could not measure what this observer observes from ``gap.start`` (to
        ``gap.end`` once it is known); each type's rule is in docs/observations.md."""
        ...

    def evaluate(self, now: float) -> list[Observation]: ...

    def describe(self) -> str:
        """One human line saying what is observed and how (for ``check-config``)."""
        ...


class ObserverBase:
    """Default no-op event handlers so an observer only writes what it uses."""

    type_name: ClassVar[str] = ""
    interval: float = 1.0
    resource: Resource

    def unavailable(self, now: float, why: str,
                    values: Mapping[str, float] | None = None) -> Observation:
        """A ``NOT_AVAILABLE`` observation saying ``why`` (waiting for data, data gone)."""
        return Observation(now, self.type_name, self.resource, Code.NOT_AVAILABLE,
                           values=dict(values or {}), message=why)

    def on_message(self, msg: MessageArrival) -> None:
        return None

    def on_graph(self, graph: GraphSnapshot) -> None:
        return None

    def on_resources(self, sample: ResourceSample) -> None:
        return None

    def on_network(self, sample: NetworkSample) -> None:
        return None

    def on_gap(self, gap: MeasurementGap) -> None:
        """Value observers keep judging what arrives: a gap in measurement does not make a
        message's values wrong, only fewer."""
        return None


class Subject(Enum):
    """What kind of resource an observer type observes."""

    TOPIC = "topic"
    TOPIC_PAIR = "topic_pair"
    NODE = "node"
    INTERFACE = "interface"


class Mode(Enum):
    """Which failure mode of its topic an observation judges (see ``docs/diagnosis.md``).

    ``LIVE``: messages arrive at the right rate; ``RIGHT``: they carry right values.
    Node and interface observers judge their component as a whole and say ``LIVE``.
    """

    LIVE = "live"
    RIGHT = "right"


@dataclass(frozen=True, slots=True)
class Quantity:
    """A quantity an observer reports, with the unit the health description publishes."""

    name: str
    unit: str = ""


@dataclass(frozen=True, slots=True)
class FixedThreshold:
    """A threshold that holds for every observer of a type, whatever its states say
    (``code`` of a liveness observer is faulty below 0)."""

    quantity: str
    type: Literal["min", "max"]
    value: float


ObserverFactory = Callable[[ConfigNode], Observer]
FilterFactory = Callable[[ConfigNode], Filter]
CheckFactory = Callable[[ConfigNode], Check]


@dataclass(frozen=True, slots=True)
class ObserverKind:
    """One observer type and everything health, diagnosis and configuration know about it.

    ``aliases`` are other spellings of the type in diagnosis model files (tug_diagnosis
    ``movement``). ``tug`` translates a tug_observers ``setup`` group of this type into
    native entries; ``tug_names`` are the group types it answers to (default: ``name``).

    ``failure_means_silent``: a failed observation of this type says its subject sends
    nothing at all (a topic that timed out, a node that is not alive), so the diagnosis
    clears that topic, or the topics of that node, of passing on wrong values.
    ``logged_values``: how many numbers one observation records in the health log (its
    quantities and extras such as ``rate_hz``), which sizes the log (``blackbox log
    capacity``).
    """

    name: str
    build: ObserverFactory
    subject: Subject
    quantities: tuple[Quantity, ...]
    judges: Mode = Mode.LIVE
    thresholds: tuple[FixedThreshold, ...] = ()
    aliases: tuple[str, ...] = ()
    tug: TugForm | None = None
    tug_names: tuple[str, ...] = ()
    exonerates: bool = True
    """Whether OK observations of this type clear the mode they judge (all of them OK, see
    docs/diagnosis.md). A learned envelope cannot see an offset inside its range, so a
    passing one is no proof of health: its type says ``False`` and it only accuses."""
    relation: bool = False
    """A relation between the values of its topics (``relation``): failed, the values of
    one of its topics are wrong; held, each of its topics' values is cleared by it alone."""
    failure_means_silent: bool = False
    judges_alive: bool = False
    """Whether it judges that its topic's signals are alive (not stuck, no noise burst):
    failed, a relation of that topic failing meanwhile may be put down to it, even where
    held relations clear the topic's values (they see offsets, not a zero-mean burst)."""
    logged_values: int = 2

    def unit(self, quantity: str) -> str:
        return next((q.unit for q in self.quantities if q.name == quantity), "")


@runtime_checkable
class NamedQuantities(Protocol):
    """An observer whose quantities are named by its configuration entry (``fields``), so
    its type registers none: the health description asks the observer instead."""

    def quantity_names(self) -> tuple[str, ...]: ...


EVIDENCE = "_evidence"
"""Suffix of a value that is a sequential test's statistic as a fraction of its alarm
threshold (0: nothing against it, 1: failed). Evidence short of an alarm orders the
candidates that explain the failures equally well (``DiagnosisEngine.rank``)."""


@dataclass(frozen=True, slots=True)
class JudgedSignals:
    """The (topic, field) signals a relation observation sees, for field-level diagnosis.

    A relation sees only the fields it relates, not its topics as a whole: failed, one of
    ``accused`` carries wrong values; OK, every one of ``cleared`` carries right values
    (``cleared`` leaves out the signals of relations that cannot see their inputs' faults).
    Other fields of the same topics are neither accused nor cleared by it (issue 22).
    """

    accused: tuple[tuple[str, str], ...]
    cleared: tuple[tuple[str, str], ...]


@runtime_checkable
class SignalJudge(Protocol):
    """An observer whose verdicts are about some fields of its topics only."""

    def judged_signals(self) -> JudgedSignals: ...


OBSERVERS: Registry[ObserverKind] = Registry("observer type", "blackbox.observe.observers")
FILTERS: Registry[FilterFactory] = Registry("filter type", "blackbox.observe.filters")
VALUE_CHECKS: Registry[CheckFactory] = Registry("value check", "blackbox.observe.checks")
CHECKS: Registry[CheckFactory] = Registry("check type", "blackbox.observe.checks")


def observer_kind(name: str) -> ObserverKind | None:
    """The observer type registered as ``name`` or with ``name`` as an alias."""
    kind = OBSERVERS.get(name)
    if kind is not None:
        return kind
    return next((k for _, k in OBSERVERS.items() if name in k.aliases), None)
