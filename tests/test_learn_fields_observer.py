"""The `fields` observer that learned configurations use: several numeric fields and
summaries of numeric arrays of one topic, judged together under one identity."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from blackbox.config.node import ConfigError
from blackbox.events import MessageArrival
from blackbox.model import Code
from blackbox.observe.build import build_observers, load_config_text
from blackbox.observe.observers.fields import FieldsObserver, summarise

CONFIG = """
observers:
  - type: fields
    topic: /scan
    fields:
      - {name: ranges_mean, field: ranges, summary: mean, filter: {type: mean, window_size: 3}}
      - {name: ranges_valid, field: ranges, summary: in_range, range: [0.1, 10.0]}
      - {name: beams, field: count}
    states:
      - number: 1
        name: nominal
        ranges_mean: {value: {type: in_between, lower_bound: 1.5, upper_bound: 2.5}}
        ranges_valid: {value: {type: greater_than, greater_than: 0.9}}
"""


def observer(text: str = CONFIG) -> FieldsObserver:
    (obs,) = build_observers(load_config_text(text, "f.yaml"))
    assert isinstance(obs, FieldsObserver)
    return obs


def scan(t: float, ranges: list[float], count: int = 4) -> MessageArrival:
    return MessageArrival(t, "/scan", "/laser", 100,
                          value=SimpleNamespace(ranges=np.asarray(ranges, dtype=np.float32),
                                                count=count))


def test_quantities_are_judged_together() -> None:
    obs = observer()
    for i in range(3):
        obs.on_message(scan(0.1 * i, [2.0, 2.1, 1.9, 2.0]))
    (ok,) = obs.evaluate(1.0)
    assert ok.code == Code.GENERAL_OK and ok.values["ranges_valid"] == 1.0
    assert ok.values["beams"] == 4.0
    for i in range(3):
        obs.on_message(scan(1.1 + 0.1 * i, [2.0, math.inf, math.nan, 20.0]))
    (bad,) = obs.evaluate(2.0)
    assert bad.code == Code.NO_STATE_FITS and bad.values["ranges_valid"] == 0.25
    assert obs.interest().decoded == frozenset({"/scan"})


def test_unreadable_samples_are_reported_not_averaged() -> None:
    obs = observer()
    obs.on_message(scan(0.1, [math.nan, math.nan]))
    (obs1,) = obs.evaluate(1.0)
    assert obs1.code == Code.GENERAL_ERROR
    assert "ranges_mean: ranges has no finite element: no mean" in obs1.message


@pytest.mark.parametrize(("summary", "expected"), [
    ("mean", 2.0), ("min", 1.0), ("max", 3.0), ("finite", 0.75),
])
def test_summaries(summary: str, expected: float) -> None:
    assert summarise([1.0, 2.0, 3.0, math.inf], summary, "x") == expected
    assert summarise(b"\x00\x02", "mean", "data") == 1.0


@pytest.mark.parametrize("dtype", [np.uint8, np.int8, np.uint16, np.int16, np.bool_])
@pytest.mark.parametrize("summary", ["mean", "min", "max", "finite", "in_range"])
def test_narrow_integers_summarise_to_the_numbers_of_their_float_copy(
        dtype: type, summary: str) -> None:
    """Frames and byte payloads are summarised without a float64 copy, to the same number."""
    rng = np.random.default_rng(7)
    for size in (1, 3, 1001, 640 * 480 * 3):
        array = rng.integers(-128 if np.dtype(dtype).kind == "i" else 0, 256,
                             size=size).astype(dtype)
        expected = summarise(array.astype(np.float64), summary, "data", (3.0, 120.5))
        assert summarise(array, summary, "data", (3.0, 120.5)) == expected
        if dtype is np.uint8:
            assert summarise(array.tobytes(), summary, "data", (3.0, 120.5)) == expected


@pytest.mark.parametrize(("entry", "error"), [
    ("{name: a, field: x, summary: median}", "expected one of"),
    ("{name: a, field: x, summary: in_range}", "needs range"),
    ("{name: a, field: x, range: [1, 2]}", "range belongs to summary in_range only"),
    ("{name: 1a, field: x}", "must be letters"),
    ("{name: a, field: 'x..y'}", "invalid field path"),
])
def test_configuration_mistakes_name_the_key(entry: str, error: str) -> None:
    text = f"observers:\n  - type: fields\n    topic: /t\n    fields:\n      - {entry}\n"
    with pytest.raises(ConfigError, match=error) as info:
        build_observers(load_config_text(text, "f.yaml"))
    assert info.value.line == 5
