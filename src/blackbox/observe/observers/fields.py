"""Several numeric fields of one topic, and summaries of numeric arrays, in one observer.

``scores`` reads one scalar. A laser scan, an IMU message or a battery state has many
numbers, and arrays whose elements are too many to observe one by one. This observer reads
any number of *quantities* from each message of one publisher group on one topic, each
through its own filter, and judges them together in one set of states, so a topic has one
value observer (one identity in records and in the diagnosis) however many of its fields
are watched:

.. code-block:: yaml

    - type: fields
      topic: /scan
      fields:
        - {name: ranges_mean, field: ranges, summary: mean, filter: {type: mean, window_size: 10}}
        - {name: ranges_valid, field: ranges, summary: in_range, range: [0.1, 30.0]}
        - {name: angle_increment, field: angle_increment}
      states:
        - number: 1
          name: nominal
          ranges_mean: {value: {type: in_between, lower_bound: 1.8, upper_bound: 2.2}}
          ranges_valid: {value: {type: greater_than, greater_than: 0.95}}

``summary`` turns the field into one number per message:

==============  ==================================================================
``value``       the field itself, a scalar (default)
``mean``        arithmetic mean of the array's finite elements
``min``         smallest finite element
``max``         largest finite element
``finite``      fraction (0..1) of elements that are finite (not NaN or infinite)
``in_range``    fraction of elements that are finite and inside ``range: [lo, hi]``
==============  ==================================================================

A message whose field cannot be read, is not a number (or not a numeric array), is NaN, or
has no finite element for ``mean``/``min``/``max`` (or no element at all) gives no sample of
that quantity and makes the next observation ``GENERAL_ERROR`` with the reason, like
``scores``; the other quantities of the same message are still counted.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from numbers import Real
from typing import Any, ClassVar

import numpy as np

from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import OBSERVERS, Mode, ObserverBase, ObserverKind, Subject, Summary
from blackbox.observe.fieldpath import compile_field_access, describe_value
from blackbox.observe.observers.entry import (
    COMMON_KEYS,
    describe_publishers,
    read_every,
    read_name,
    read_publishers,
    read_quantity,
)
from blackbox.observe.observers.quantity import (
    FilteredQuantity,
    SampleProblems,
    describe_states_inline,
    judge,
    number,
)
from blackbox.observe.states import StateSpec, parse_states

SUMMARIES = ("value", "mean", "min", "max", "finite", "in_range")
_NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")


def _as_array(value: Any, path: str) -> np.ndarray:
    """``value`` as a flat numeric array. Booleans and integers of up to 16 bits (camera
    frames, byte payloads) keep their type: every sum of them short of 2**37 elements is an
    integer below 2**53, exact in float64 in any order, so their mean, minimum and maximum
    are the very numbers of a float64 copy, without making one (four such copies per frame
    were most of the learner's CPU on the simulated thesis robot's camera)."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return np.frombuffer(value, dtype=np.uint8)
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):  # ragged or not array-like
        raise ValueError(f"{path} is {describe_value(value)}, not a numeric array") from None
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{path} is {describe_value(value)}, not a numeric array")
    if _exact_integers(array):
        return array.ravel()
    return array.astype(np.float64, copy=False).ravel()


def _exact_integers(array: np.ndarray) -> bool:
    """Booleans or integers narrow enough that float64 sums of them are exact."""
    return array.dtype.kind in "biu" and array.dtype.itemsize <= 2


def _summarise_integers(array: np.ndarray, summary: str,
                        bounds: tuple[float, float] | None) -> float:
    """``summary`` of a non-empty integer array: every element is finite."""
    if summary == "finite":
        return 1.0
    if summary == "in_range":
        lo, hi = bounds if bounds is not None else (-math.inf, math.inf)
        return float(((array >= lo) & (array <= hi)).mean())
    if summary == "mean":
        return float(array.mean(dtype=np.float64))
    if summary == "min":
        return float(array.min())
    return float(array.max())


def summarise(value: Any, summary: str, path: str,
              bounds: tuple[float, float] | None = None) -> float:
    """One number for ``value`` (the field at ``path``) by ``summary``; ``ValueError`` with
    the reason when there is none."""
    if summary == "value":
        if isinstance(value, Real):
            return float(value)
        if getattr(value, "ndim", None) == 0 and getattr(value, "dtype", None) is not None \
                and value.dtype.kind in "biuf":
            return float(value)
        raise ValueError(f"{path} is {describe_value(value)}, not a number")
    array = _as_array(value, path)
    if array.size == 0:
        raise ValueError(f"{path} is empty: no {summary}")
    if _exact_integers(array):
        return _summarise_integers(array, summary, bounds)
    finite = np.isfinite(array)
    if summary == "finite":
        return float(finite.mean())
    if summary == "in_range":
        lo, hi = bounds if bounds is not None else (-math.inf, math.inf)
        with np.errstate(invalid="ignore"):
            inside = finite & (array >= lo) & (array <= hi)
        return float(inside.mean())
    kept = array[finite] if not finite.all() else array
    if kept.size == 0:
        raise ValueError(f"{path} has no finite element: no {summary}")
    if summary == "mean":
        return float(kept.mean())
    if summary == "min":
        return float(kept.min())
    return float(kept.max())


@dataclass(frozen=True, slots=True)
class FieldQuantity:
    """How one named quantity comes out of a message."""

    name: str
    field: str
    summary: str = "value"
    bounds: tuple[float, float] | None = None

    def describe(self) -> str:
        if self.summary == "value":
            return self.field
        if self.summary == "in_range" and self.bounds is not None:
            return f"in_range({self.field}, {self.bounds[0]:g}..{self.bounds[1]:g})"
        return f"{self.summary}({self.field})"


class FieldsObserver(ObserverBase):
    """Named numeric quantities of every message of one publisher group on one topic."""

    type_name: ClassVar[str] = "fields"

    def __init__(self, topic: str, quantities: Sequence[tuple[FieldQuantity, FilteredQuantity]],
                 states: Sequence[StateSpec] = (), publishers: Sequence[str] = (),
                 every: float = 1.0) -> None:
        if not quantities:
            raise ValueError("a fields observer needs at least one field")
        self.topic = topic
        self.publishers = tuple(publishers)
        self.quantities = tuple(quantities)
        self.states = tuple(states)
        self.interval = every
        self.resource = Resource(topic=topic, publishers=self.publishers)
        self._group = frozenset(self.publishers)
        self._readers: list[tuple[Callable[[Any], Any], FieldQuantity,
                                  Callable[[float], None]]] = [
            (compile_field_access(spec.field), spec, filtered.update)
            for spec, filtered in self.quantities]
        self._problems = SampleProblems()

    def interest(self) -> Interest:
        return Interest(decoded=frozenset({self.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        if self._group and msg.publisher not in self._group:
            return
        value = self._problems.value_of(msg)
        if value is None:
            return
        for access, spec, update in self._readers:
            try:
                x = summarise(access(value), spec.summary, spec.field, spec.bounds)
            except ValueError as exc:
                self._problems.add(f"{spec.name}: {exc}")
                continue
            if not math.isfinite(x):
                self._problems.add(f"{spec.name}: {spec.field} is {x}, not a finite number")
                continue
            update(x)

    def quantity_names(self) -> tuple[str, ...]:
        """The quantities this entry names; the type registers none of its own."""
        return tuple(spec.name for spec, _ in self.quantities)

    def summaries(self) -> dict[str, Summary | None]:
        return {spec.name: filtered.summary() for spec, filtered in self.quantities}

    def evaluate(self, now: float) -> list[Observation]:
        summaries = self.summaries()
        present = {k: s.value for k, s in summaries.items() if s is not None}
        skipped = self._problems.report(now, self.type_name, self.resource, present or None)
        if skipped is not None:
            return [skipped]
        missing = [k for k, s in summaries.items() if s is None]
        if missing:
            return [Observation(now, self.type_name, self.resource, Code.NOT_AVAILABLE,
                                values=present,
                                message=f"waiting for a first sample of {', '.join(missing)}")]
        verdict = judge(self.states, summaries)
        shown = ", ".join(f"{k} {number(v)}" for k, v in present.items())
        return [Observation(now, self.type_name, self.resource, verdict.code, verdict.states,
                            verdict.values, f"{shown} {verdict.fits}")]

    def describe(self) -> str:
        group = describe_publishers(self.publishers)
        what = ", ".join(f"{spec.name} = {filtered.describe().replace(' of ' + spec.name, '')}"
                         f" of {spec.describe()}" for spec, filtered in self.quantities)
        return (f"fields {self.topic} [{group}]: {what}; "
                f"{describe_states_inline(self.states)}, every {self.interval:g} s")


def _quantity(node: ConfigNode, names: set[str]) -> tuple[FieldQuantity, FilteredQuantity]:
    node.check_keys(("name", "field", "summary", "range", "filter"))
    name_node = node["name"]
    name = name_node.str()
    if not name or not set(name) <= _NAME_CHARS or name[0].isdigit():
        raise name_node.error(f"quantity name {name!r} must be letters, digits and '_', not "
                              "starting with a digit")
    if name in names:
        raise name_node.error(f"quantity {name!r} named twice")
    names.add(name)
    field_node = node["field"]
    path = field_node.str()
    try:
        compile_field_access(path)
    except ValueError as exc:
        raise field_node.error(str(exc)) from None
    summary_node = node.get("summary")
    summary = "value" if summary_node is None else summary_node.str(SUMMARIES)
    bounds = None
    range_node = node.get("range")
    if summary == "in_range":
        if range_node is None:
            raise node.error("summary in_range needs range: [low, high]")
        items = range_node.list()
        if len(items) != 2:
            raise range_node.error("range must be [low, high]")
        lo, hi = items[0].float(), items[1].float()
        if not lo <= hi:
            raise range_node.error(f"range low {lo:g} is above high {hi:g}")
        bounds = (lo, hi)
    elif range_node is not None:
        raise range_node.error("range belongs to summary in_range only")
    return FieldQuantity(name, path, summary, bounds), read_quantity(node, "filter", name)


def fields_from_config(node: ConfigNode) -> FieldsObserver:
    node.check_keys((*COMMON_KEYS, "topic", "publishers", "fields", "states"))
    fields_node = node["fields"]
    entries = fields_node.list()
    if not entries:
        raise fields_node.error("fields lists no field")
    names: set[str] = set()
    quantities = []
    for entry in entries:
        if not entry.is_map:
            raise entry.error("expected a field entry ({name: ..., field: ...})")
        quantities.append(_quantity(entry, names))
    return FieldsObserver(
        topic=read_name(node, "topic"),
        quantities=quantities,
        states=parse_states(node.get("states"), tuple(q.name for q, _ in quantities)),
        publishers=read_publishers(node),
        every=read_every(node),
    )


OBSERVERS.add("fields", ObserverKind("fields", fields_from_config, Subject.TOPIC, (),
                                     judges=Mode.RIGHT, exonerates=False), example={
    "type": "fields", "topic": "/scan",
    "fields": [{"name": "ranges_mean", "field": "ranges", "summary": "mean",
                "filter": {"type": "mean", "window_size": 3}},
               {"name": "ranges_valid", "field": "ranges", "summary": "in_range",
                "range": [0.1, 10.0]}],
    "states": [{"number": 1, "name": "ok",
                "ranges_mean": {"value": {"type": "less_than", "less_than": 10.0}}}]})
