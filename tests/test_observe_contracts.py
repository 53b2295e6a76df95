"""The contract every registered filter, check and observer kind keeps, checked for each.

Hand-written tests (``test_filters.py``, ``test_checks.py``, ``test_observers_*.py``) pin each
kind's own arithmetic; this module checks what all kinds of a family share, in the style of
river's estimator checks. It is parametrised over the registries themselves, so a kind added
anywhere, including a one-file plug-in dropped into ``tests/plugins/``, is covered without
a line changed here. Each kind is built from the ``example`` configuration it registers
with (:meth:`blackbox.registry.Registry.add`); a kind registered without one fails here.

The shared contract: built from configuration; a defined answer before any input; results
that depend on the input alone (the same input gives the same output and no clock is read);
NaN and infinite input neither raises nor poisons later results; ``reset`` forgets
everything (filters); checks keep no history; observers report under their registered
type and resource, and take an :class:`~blackbox.events.ArrivalBatch` exactly as that many
single arrivals.
"""

from __future__ import annotations

import importlib
import json
import math
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from blackbox.config.node import ConfigNode
from blackbox.events import (
    ArrivalBatch,
    GraphSnapshot,
    MessageArrival,
    NetworkSample,
    NodeInfo,
    ResourceSample,
)
from blackbox.model import Code, Observation
from blackbox.observe.base import CHECKS, FILTERS, OBSERVERS, VALUE_CHECKS, Observer, Summary
from blackbox.observe.build import build_observer
from blackbox.registry import Registry
from blackbox.sources.base import SOURCES

PLUGIN_DIR = Path(__file__).parent / "plugins"
REGISTRIES: dict[str, Registry[Any]] = {"filter": FILTERS, "check": CHECKS,
                                        "value_check": VALUE_CHECKS, "observer": OBSERVERS}


def plugin_modules() -> list[str]:
    return [f"plugins.{p.stem}" for p in sorted(PLUGIN_DIR.glob("*.py"))
            if not p.stem.startswith("_")]


@contextmanager
def plugins_registered() -> Iterator[None]:
    """Every module of ``tests/plugins`` imported (so registered), and forgotten after, so
    other test modules that import them themselves find the registries as before."""
    watched = [*REGISTRIES.values(), SOURCES]
    before = [set(registry) for registry in watched]
    for module in plugin_modules():
        sys.modules.pop(module, None)
        importlib.import_module(module)
    try:
        yield
    finally:
        for registry, names in zip(watched, before, strict=True):
            for name in set(registry) - names:
                registry.remove(name)
        for module in plugin_modules():
            sys.modules.pop(module, None)


def registered(family: str) -> list[str]:
    with plugins_registered():
        return list(REGISTRIES[family])


@pytest.fixture(autouse=True, scope="module")
def _plugins() -> Iterator[None]:
    with plugins_registered():
        yield


def example_node(family: str, name: str) -> ConfigNode:
    registry = REGISTRIES[family]
    example = registry.example(name)
    assert example is not None, (
        f"{registry.what} {name!r} registers no example configuration: give one to "
        f"{family.upper()}S.add({name!r}, ..., example={{'type': {name!r}, ...}}) so the "
        f"contract tests can build it")
    return ConfigNode.parse(json.dumps(example), f"example of {registry.what} {name}")


@contextmanager
def no_clock(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Reading the wall or monotonic clock fails the test: time is always passed in."""

    def clock_read(*_: object) -> float:
        raise AssertionError("an observation-layer kind read the clock; time is passed in")

    with monkeypatch.context() as patch:
        for name in ("time", "monotonic", "perf_counter", "time_ns", "monotonic_ns"):
            patch.setattr(time, name, clock_read)
        yield


def test_every_family_has_kinds_and_the_plugins_are_included() -> None:
    """The parameters below come from the registries with ``tests/plugins`` imported."""
    assert {"mean", "median", "ewma", "kmeans", "nofilter"} <= set(FILTERS)
    assert {"nominal_value", "student_t"} <= set(CHECKS)
    assert {"hz", "timeout", "activated"} <= set(OBSERVERS)
    assert "burst" in OBSERVERS, "tests/plugins/burst_observer.py is not covered"


@pytest.mark.parametrize(("family", "name"), [(family, name) for family in REGISTRIES
                                              for name in registered(family)])
def test_every_kind_registers_an_example_that_builds(family: str, name: str) -> None:
    node = example_node(family, name)
    built = REGISTRIES[family][name](node) if family != "observer" else build_observer(node)
    assert built is not None


# ---- filters ------------------------------------------------------------------------------

SAMPLES = (1.0, 1.2, 0.9, 1.1, 5.0, 1.0, 0.95, 1.05, 1.3, 0.8, 1.0, 1.15)
NOT_FINITE = (math.nan, math.inf, -math.inf)


def build_filter_kind(name: str) -> Any:
    return FILTERS[name](example_node("filter", name))


def fed(name: str, xs: Sequence[float]) -> Any:
    f = build_filter_kind(name)
    for x in xs:
        f.update(x)
    return f


def assert_empty(f: Any) -> None:
    assert (f.get(), f.deviation(), f.summary(), f.count()) == (None, None, None, 0)


@pytest.mark.parametrize("name", registered("filter"))
def test_a_filter_before_any_sample_says_nothing(name: str) -> None:
    assert_empty(build_filter_kind(name))


@pytest.mark.parametrize("name", registered("filter"))
def test_a_filter_summary_agrees_with_get_deviation_and_count(name: str) -> None:
    for n in range(1, len(SAMPLES) + 1):
        f = fed(name, SAMPLES[:n])
        value, summary = f.get(), f.summary()
        assert summary == Summary(value, f.deviation(), f.count())
        assert 1 <= f.count() <= n
        assert min(SAMPLES[:n]) <= value <= max(SAMPLES[:n]), \
            f"{name}: {value} is outside the samples it filtered"
        deviation = f.deviation()
        assert deviation is None or (math.isfinite(deviation) and deviation >= 0.0)


@pytest.mark.parametrize("name", registered("filter"))
def test_a_filter_depends_on_its_samples_alone(name: str,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    with no_clock(monkeypatch):
        first, second = fed(name, SAMPLES), fed(name, SAMPLES)
        assert first.summary() == second.summary()
        assert first.summary() == first.summary(), "reading a summary changed it"


@pytest.mark.parametrize("name", registered("filter"))
def test_a_filter_ignores_nan_and_infinite_samples(name: str) -> None:
    dirty = [x for s in SAMPLES for x in (s, *NOT_FINITE)]
    assert fed(name, dirty).summary() == fed(name, SAMPLES).summary()
    assert_empty(fed(name, NOT_FINITE))


@pytest.mark.parametrize("name", registered("filter"))
def test_a_reset_filter_is_as_new(name: str) -> None:
    f = fed(name, SAMPLES)
    f.reset()
    assert_empty(f)
    for x in SAMPLES[3:]:
        f.update(x)
    assert f.summary() == fed(name, SAMPLES[3:]).summary()


# ---- checks -------------------------------------------------------------------------------

SUMMARIES = [Summary(v, d, n) for v in (-1.0, 0.0, 0.5, 1.0, 1.2, 2.5, 1e9)
             for d in (None, 0.0, 0.1, 3.0) for n in (1, 2, 30)]
ODD_SUMMARIES = [Summary(v, d, n) for v in (*NOT_FINITE, 1.0) for d in (None, *NOT_FINITE)
                 for n in (0, 2)]
CHECK_FAMILIES = [(family, name) for family in ("check", "value_check")
                  for name in registered(family)]


def build_check_kind(family: str, name: str) -> Any:
    return REGISTRIES[family][name](example_node(family, name))


@pytest.mark.parametrize(("family", "name"), CHECK_FAMILIES)
def test_a_check_answers_yes_or_no_and_describes_itself(family: str, name: str) -> None:
    check = build_check_kind(family, name)
    answers = [check.test(s) for s in SUMMARIES]
    assert all(type(a) is bool for a in answers)
    assert True in answers or name == "not_in_between" or False in answers
    assert isinstance(check.describe(), str) and check.describe()


@pytest.mark.parametrize(("family", "name"), CHECK_FAMILIES)
def test_a_check_keeps_no_history_and_reads_no_clock(family: str, name: str,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The answer for a summary is the same fresh, after others, and from a twin."""
    # Once outside the guard: a library's lazy first import (scipy's, for student_t in a
    # fresh worker process) may read the clock; the check's own evaluations must not.
    warm = build_check_kind(family, name)
    for summary in SUMMARIES:
        warm.test(summary)
    with no_clock(monkeypatch):
        check, twin = build_check_kind(family, name), build_check_kind(family, name)
        first = [check.test(s) for s in SUMMARIES]
        assert [check.test(s) for s in reversed(SUMMARIES)] == first[::-1]
        assert [twin.test(s) for s in SUMMARIES] == first


@pytest.mark.parametrize(("family", "name"), CHECK_FAMILIES)
def test_a_check_takes_nan_and_infinite_summaries_without_raising(family: str,
                                                                  name: str) -> None:
    check = build_check_kind(family, name)
    assert all(type(check.test(s)) is bool for s in ODD_SUMMARIES)


@pytest.mark.parametrize("name", registered("value_check"))
def test_a_value_check_tests_a_summary_by_its_value(name: str) -> None:
    check = build_check_kind("value_check", name)
    for s in SUMMARIES:
        assert check.test(s) is check.passes(s.value)


# ---- observers ----------------------------------------------------------------------------

T0 = 1_000.0
SPAN = 4.0
PUBLISHER = "/publisher"


class AnyField(float):
    """A decoded message whose every field, at any depth, reads this number (so any field
    path of any example finds a value)."""

    def __getattr__(self, name: str) -> AnyField:
        if name.startswith("__"):
            raise AttributeError(name)
        return self


class NanMessage:
    """A decoded message whose every field, at any depth, is NaN (a broken sensor)."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return math.nan


def build_observer_kind(name: str) -> Observer:
    return build_observer(example_node("observer", name))


Event = MessageArrival | ArrivalBatch | GraphSnapshot | ResourceSample | NetworkSample


def steady(i: int) -> AnyField:
    return AnyField(1.0 + 0.01 * (i % 3))


def events_for(observer: Observer, value: Callable[[int], Any] = steady,
               number: Callable[[int], float] = float) -> list[Event]:
    """What a robot would send for ``observer.interest()`` over ``SPAN`` seconds: its
    topics at 10 Hz (decoded values from ``value``), its nodes alive, their resources and
    the network, numbers from ``number``."""
    want = observer.interest()
    out: list[Event] = []
    for i in range(int(SPAN * 10)):
        t = T0 + i * 0.1
        for topic in sorted(want.topics | want.decoded):
            out.append(MessageArrival(t, topic, PUBLISHER, 100, value=value(i)))
        if i % 5 == 0:
            nodes = {n: NodeInfo(n, True, pid=100) for n in sorted(want.nodes | want.resources)}
            out.append(GraphSnapshot(t, nodes=nodes))
            for node in sorted(want.resources):
                out.append(ResourceSample(t, node, number(i), number(i) * 1e6))
            if want.network:
                out.append(NetworkSample(t, "eth0", 1000 * i, 500 * i))
    return out


def run(observer: Observer, events: Sequence[Event]) -> list[Observation]:
    """Feed ``events`` in time order and evaluate every ``interval`` as the pipeline does."""
    out: list[Observation] = []
    due = T0 + observer.interval
    for event in events:
        while event.time >= due:
            out += observer.evaluate(due)
            due += observer.interval
        deliver(observer, event)
    while due <= T0 + SPAN + observer.interval:
        out += observer.evaluate(due)
        due += observer.interval
    return out


def deliver(observer: Observer, event: Event) -> None:
    if isinstance(event, MessageArrival):
        observer.on_message(event)
    elif isinstance(event, ArrivalBatch):
        on_batch = getattr(observer, "on_batch", None)
        if on_batch is not None:
            on_batch(event)
        else:
            for arrival in event.arrivals():
                observer.on_message(arrival)
    elif isinstance(event, GraphSnapshot):
        observer.on_graph(event)
    elif isinstance(event, ResourceSample):
        observer.on_resources(event)
    else:
        observer.on_network(event)


def assert_well_formed(name: str, observer: Observer, observations: Sequence[Observation]
                       ) -> None:
    for o in observations:
        assert isinstance(o, Observation)
        assert o.observer == name, f"{name} reports as {o.observer!r}"
        assert o.resource == observer.resource
        assert o.code in set(Code)
        assert all(isinstance(v, float | int) for v in o.values.values())


@pytest.mark.parametrize("name", registered("observer"))
def test_an_observer_reports_under_its_type_and_resource(name: str) -> None:
    observer = build_observer_kind(name)
    assert observer.type_name == name
    assert observer.interval > 0
    assert isinstance(observer.describe(), str) and observer.describe()
    observations = run(observer, events_for(observer))
    assert observations, f"{name} made no observation in {SPAN} s"
    assert_well_formed(name, observer, observations)
    assert any(o.code is not Code.NOT_AVAILABLE for o in observations), \
        f"{name} never judged its input: {observations[-1].message}"


@pytest.mark.parametrize("name", registered("observer"))
def test_an_observer_says_not_available_for_undecodable_messages(name: str) -> None:
    """A source that cannot decode a topic hands out ``None`` values."""
    observer = build_observer_kind(name)
    assert_well_formed(name, observer, run(observer, events_for(observer, value=lambda i: None)))


@pytest.mark.parametrize("name", registered("observer"))
def test_an_observer_without_input_says_so(name: str) -> None:
    """Before any event the verdict is defined (usually ``NOT_AVAILABLE``), never a crash."""
    observer = build_observer_kind(name)
    observations = run(observer, [])
    assert_well_formed(name, observer, observations)


@pytest.mark.parametrize("name", registered("observer"))
def test_an_observer_depends_on_its_input_alone(name: str,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    with no_clock(monkeypatch):
        runs = [run(build_observer_kind(name), events_for(build_observer_kind(name),
                                                           number=lambda i: 10.0 + i % 3))
                for _ in range(2)]
    assert repr(runs[0]) == repr(runs[1])


@pytest.mark.parametrize("name", registered("observer"))
def test_an_observer_takes_nan_and_infinite_input(name: str) -> None:
    """Broken numbers (a NaN CPU load, NaN message fields) neither raise nor end up as
    reported values."""
    observer = build_observer_kind(name)
    odd = (*NOT_FINITE, 1.0)
    observations = run(observer, events_for(observer, value=lambda i: NanMessage(),
                                            number=lambda i: odd[i % len(odd)]))
    assert_well_formed(name, observer, observations)
    for o in observations:
        assert all(math.isfinite(v) for v in o.values.values()), \
            f"{name} reported {o.values} at {o.time}"


@pytest.mark.parametrize("name", registered("observer"))
def test_an_observer_takes_a_batch_as_that_many_arrivals(name: str) -> None:
    """What a batching source hands out is what one arrival per message would have been."""
    single, batched = build_observer_kind(name), build_observer_kind(name)
    timing_only = sorted(single.interest().topics - single.interest().decoded)
    if not timing_only:
        pytest.skip(f"{name} reads no timing-only topic")
    events: list[Event] = [
        ArrivalBatch(T0 + 0.3 * i, topic, PUBLISHER, 1 + i % 4, 100 * (1 + i % 4))
        for i in range(int(SPAN / 0.3)) for topic in timing_only]
    one_by_one: list[Event] = [a for e in events if isinstance(e, ArrivalBatch)
                               for a in e.arrivals()]
    assert repr(run(batched, events)) == repr(run(single, one_by_one))
