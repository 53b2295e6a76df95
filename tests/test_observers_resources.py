"""resources observer: CPU and memory of a node, never a silent zero."""

from __future__ import annotations

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, ResourceSample
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS

CONFIG = """\
type: resources
node: /camera
cpu_filter: {type: mean, window_size: 3}
memory_filter: {type: median, window_size: 3}
states:
  - number: 1
    name: normal
    cpu: {value: {type: less_than, less_than: 50}}
    memory: {value: {type: less_than, less_than: 200000000}}
  - number: 2
    name: busy
    cpu: {value: {type: greater_than, greater_than: 40}}
"""


def build(text: str = CONFIG):
    return OBSERVERS["resources"].build(ConfigNode.parse(text, "t.yaml"))


def sample(t: float, cpu: float | None, memory: float | None, reason: str = "",
           node: str = "/camera") -> ResourceSample:
    return ResourceSample(t, node, cpu, memory, reason)


def test_normal_load() -> None:
    rs = build()
    for t, cpu, mem in [(1, 10.0, 100e6), (2, 20.0, 120e6), (3, 30.0, 110e6)]:
        rs.on_resources(sample(t, cpu, mem))
    [obs] = rs.evaluate(3.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.resource == Resource(node="/camera")
    assert obs.states == (State(1, "normal"),)
    assert obs.values["cpu"] == pytest.approx(20.0)
    assert obs.values["memory"] == 110e6
    assert obs.values["cpu_deviation"] == pytest.approx(10.0)
    assert obs.message == "cpu 20 %, memory 110 MB fits 'normal'"


def test_several_states_fit_at_once() -> None:
    rs = build()
    rs.on_resources(sample(1, 45.0, 100e6))
    [obs] = rs.evaluate(1.0)
    assert obs.states == (State(1, "normal"), State(2, "busy"))
    assert obs.message.endswith("fits 'normal', 'busy'")


def test_memory_leak_fits_no_state() -> None:
    rs = build()
    for t, mem in [(1, 150e6), (2, 250e6), (3, 300e6)]:
        rs.on_resources(sample(t, 10.0, mem))
    [obs] = rs.evaluate(3.0)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.values["memory"] == 250e6


def test_missing_values_are_not_available_with_the_reason() -> None:
    rs = build()
    rs.on_resources(sample(1, 10.0, 100e6))
    rs.on_resources(sample(2, None, None, "process 4242 is gone"))
    [obs] = rs.evaluate(2.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "no cpu and memory value for /camera: process 4242 is gone"
    rs.on_resources(sample(3, 12.0, None, "permission denied"))
    [obs] = rs.evaluate(3.0)
    assert obs.message == "no memory value for /camera: permission denied"
    rs.on_resources(sample(4, 14.0, 100e6))
    [obs] = rs.evaluate(4.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.values["cpu"] == pytest.approx((10.0 + 12.0 + 14.0) / 3)


def test_other_nodes_are_ignored_and_first_sample_awaited() -> None:
    rs = build()
    rs.on_resources(sample(1, 99.0, 1e9, node="/other"))
    [obs] = rs.evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for the first resource sample of /camera"


def test_without_filters_and_states() -> None:
    rs = build("type: resources\nnode: /camera\n")
    rs.on_resources(sample(1, 5.0, 2048.0))
    [obs] = rs.evaluate(1.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.values == {"cpu": 5.0, "memory": 2048.0}
    assert obs.message == "cpu 5 %, memory 2.05 kB (no states configured)"


def test_interest_and_describe() -> None:
    rs = build()
    assert rs.interest() == Interest(resources=frozenset({"/camera"}))
    assert rs.describe().startswith(
        "resources /camera: mean (window 3, deviation std_deviation) of cpu, median (window 3")


def test_config_errors() -> None:
    with pytest.raises(ConfigError) as err:
        build("type: resources\nnode: /a\nmem_filter: {type: mean, window_size: 3}\n")
    assert err.value.line == 3
    assert "unknown key 'mem_filter'; did you mean 'memory_filter'?" in err.value.message
    with pytest.raises(ConfigError) as err:
        build("type: resources\nnode: /a\ncpu_filter: {type: mean}\n")
    assert err.value.line == 3
    assert "window_size" in err.value.message
