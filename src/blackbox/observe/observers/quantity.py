"""Filtered quantities and the verdict of configured states on them.

Most observers measure one or more named quantities (``period``, ``score``, ``cpu``, ...),
feed each through its own filter and ask the configured states which of them fit the
filtered summaries. This module holds that shared part, so an observer only says how its
samples come about.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from blackbox.events import MessageArrival
from blackbox.model import Code, Observation, Resource, State
from blackbox.observe.base import Filter, ObserverBase, Summary
from blackbox.observe.states import StateSpec, describe_states, evaluate_states


class FilteredQuantity:
    """One named quantity and the filter its samples go through.

    ``update`` is the filter's own bound method, so the hot path calls it directly.
    """

    __slots__ = ("filter", "name", "update")

    def __init__(self, name: str, filter: Filter) -> None:
        self.name = name
        self.filter = filter
        self.update = filter.update

    def summary(self) -> Summary | None:
        return self.filter.summary()

    def provisional_summary(self, sample: float) -> Summary | None:
        """The summary as if ``sample`` were the next sample; the filter stays unchanged.

        Used for quantities whose next sample is known to be at least ``sample`` before it
        arrives (a period or a delay still running), so a stall shows without waiting.
        """
        probe = copy.deepcopy(self.filter)
        probe.update(sample)
        return probe.summary()

    def describe(self) -> str:
        describe = getattr(self.filter, "describe", None)
        how = describe() if callable(describe) else type(self.filter).__name__
        return f"{how} of {self.name}"


@dataclass(frozen=True, slots=True)
class Verdict:
    """What the states say about a set of summaries."""

    code: Code
    states: tuple[State, ...]
    values: dict[str, float] = field(default_factory=dict)
    fits: str = ""


class SampleProblems:
    """Messages since the last evaluation: how many arrived, how many gave no sample, and
    the latest reason why.

    Used by the observers that read values out of messages (scores, timestamp, motion).
    """

    __slots__ = ("count", "reason", "seen", "undecodable")

    def __init__(self) -> None:
        self.seen = 0
        self.clear()

    def add(self, reason: str, undecodable: bool = False) -> None:
        self.count += 1
        self.reason = reason
        self.undecodable = undecodable

    def clear(self) -> None:
        self.count = 0
        self.reason = ""
        self.undecodable = False

    def value_of(self, msg: MessageArrival, label: str = "") -> Any:
        """Counts ``msg`` as seen; ``msg.value``, or ``None`` after recording why there is none.

        A decoder failing on malformed bytes is the robot's garbage, never the black box's
        crash: it becomes an unreadable message like any other.
        """
        self.seen += 1
        prefix = f"{label}: " if label else ""
        try:
            value = msg.value
        except Exception as exc:
            self.add(f"{prefix}message does not decode: {exc}")
            return None
        if value is None:
            self.add(f"{prefix}the source cannot decode this topic", undecodable=True)
        return value

    def report(self, now: float, observer: str, resource: Resource,
               values: Mapping[str, float] | None = None) -> Observation | None:
        """The observation reporting the messages skipped since the last evaluation (with
        ``values`` after the ``skipped`` count), ``None`` when none was. Either way the next
        evaluation counts afresh.
        """
        seen, self.seen = self.seen, 0
        if not self.count:
            return None
        code = Code.NOT_AVAILABLE if self.undecodable else Code.GENERAL_ERROR
        message = (f"{self.count} of {seen} messages since the last evaluation unreadable: "
                   f"{self.reason}")
        observation = Observation(now, observer, resource, code,
                                  values={"skipped": float(self.count), **(values or {})},
                                  message=message)
        self.clear()
        return observation


class JudgedObserver(ObserverBase):
    """An observer whose filtered quantities the configured states judge.

    Holds what every such observer has (resource, quantities, states, interval) and says
    it back in ``describe()``; a subclass says what it observes in :meth:`subject` and how
    its samples come about.
    """

    def __init__(self, resource: Resource, quantities: Sequence[FilteredQuantity],
                 states: Sequence[StateSpec], every: float) -> None:
        self.resource = resource
        self.quantities = tuple(quantities)
        self.states = tuple(states)
        self.interval = every

    def subject(self) -> str:
        """What is observed, as ``describe()`` names it."""
        return self.resource.label()

    def filtering(self) -> str:
        """How the samples are filtered, as ``describe()`` says it."""
        return ", ".join(q.describe() for q in self.quantities)

    def describe(self) -> str:
        return (f"{self.type_name} {self.subject()}: {self.filtering()}; "
                f"{describe_states_inline(self.states)}, every {self.interval:g} s")

    def judged(self, now: float, summaries: Mapping[str, Summary | None], measured: str,
               extra: Mapping[str, float] | None = None, note: str = "") -> Observation:
        """The states' verdict on ``summaries``; the message is ``measured``, the states
        that fit and ``note``; ``extra`` values follow the summaries' values."""
        verdict = judge(self.states, summaries)
        values = {**verdict.values, **(extra or {})}
        return Observation(now, self.type_name, self.resource, verdict.code, verdict.states,
                           values, f"{measured} {verdict.fits}{note}")


def summary_values(summaries: Mapping[str, Summary | None]) -> dict[str, float]:
    """``{name: value, name_deviation: deviation}`` for every summary that exists."""
    values: dict[str, float] = {}
    for name, s in summaries.items():
        if s is None:
            continue
        values[name] = s.value
        if s.deviation is not None:
            values[f"{name}_deviation"] = s.deviation
    return values


def judge(states: Sequence[StateSpec], summaries: Mapping[str, Summary | None]) -> Verdict:
    """The code, fitting states, values and a short ``fits ...`` phrase for a message."""
    code, fitting = evaluate_states(states, summaries)
    return Verdict(code, fitting, summary_values(summaries), fits_phrase(states, fitting))


def fits_phrase(states: Sequence[StateSpec], fitting: Sequence[State]) -> str:
    if not states:
        return "(no states configured)"
    if fitting:
        return "fits " + ", ".join(repr(s.name) for s in fitting)
    expected = ", ".join(repr(s.name) for s in states)
    return f"fits no state (expected {expected})"


def describe_states_inline(states: Sequence[StateSpec]) -> str:
    """The states in an observer's one-line ``describe()``."""
    return describe_states(states, "; ") if states else "no states"


def number(x: float) -> str:
    """A measured value for a message: four significant digits."""
    return f"{x:.4g}"


def byte_count(x: float) -> str:
    """Bytes with a binary-free SI unit: ``1.25 MB``."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.3g} {unit}"
    return f"{x:.3g} B"
