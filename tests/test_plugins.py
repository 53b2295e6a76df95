"""A new observer type and a new source are one file each (tests/plugins/): once their
module is imported, configuration, health description, diagnosis and the run itself know
them, without a line changed anywhere else."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from blackbox.app import RunOptions, build
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.diagnose.robot_model import (
    ObservationSpec,
    TopicStructure,
    is_rate_type,
    parse_robot_model,
)
from blackbox.health.describe import ThresholdSpec, describe_observer
from blackbox.health.mapping import HealthMapper
from blackbox.health.types import C_Monitored_Characteristic_Specification, C_Threshold
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import OBSERVERS
from blackbox.observe.build import build_observers, load_config
from blackbox.sinks import SinkBase
from blackbox.sources.base import SOURCES

NATIVE = """\
observers:
  - type: burst
    topic: /toy
    states:
      - {number: 1, name: steady, burst: {value: {type: in_between, lower_bound: 8,
                                                  upper_bound: 12}}}
  - {type: hz, topic: /toy}
"""

TUG = """\
setup:
  - type: burst
    main_loop_rate: 2.0
    topics:
      - name: /toy
        states:
          - {state: steady, number: 1, messages: {value: {type: greater_than,
                                                          greater_than: 2}}}
"""

MODEL = """\
nodes:
  - {name: /toy_node, pub_topic: [/toy]}
observations:
  - {type: burst, topics: [/toy]}
  - {type: hz, topics: [/toy]}
"""


@pytest.fixture
def plugins() -> Iterator[None]:
    """Import both plug-in modules (registering them) and forget them afterwards."""
    for module in ("plugins.burst_observer", "plugins.toy_source"):
        sys.modules.pop(module, None)
        importlib.import_module(module)
    yield
    OBSERVERS.remove("burst")
    SOURCES.remove("toy")
    for module in ("plugins.burst_observer", "plugins.toy_source"):
        sys.modules.pop(module, None)


class Collect(SinkBase):
    def __init__(self) -> None:
        self.observations: list[Observation] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self.observations.extend(observations)


def write(tmp_path: Path, text: str, name: str = "robot.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_the_plugin_observer_loads_in_both_formats(plugins: None, tmp_path: Path) -> None:
    native = build_observers(load_config(write(tmp_path, NATIVE)))
    tug = build_observers(load_config(write(tmp_path, TUG, "tug.yaml")))
    assert [o.type_name for o in native] == ["burst", "hz"]
    assert [o.describe() for o in tug] == [
        "burst /toy: nofilter (all samples, deviation std_deviation) of burst; "
        "state 1 'steady': burst: value > 2, every 0.5 s"]


def test_the_plugin_observer_publishes_its_unit_and_thresholds(plugins: None,
                                                               tmp_path: Path) -> None:
    entry = load_config(write(tmp_path, NATIVE)).observers[0]
    d = describe_observer(entry)
    assert d.quantities == ("burst",) and d.unit("burst") == "msg"
    assert d.thresholds == (ThresholdSpec("burst", "min", 8.0), ThresholdSpec("burst", "max", 12.0),
                            ThresholdSpec("burst", "min", 1.0))
    mapper = HealthMapper("toy", descriptions=[d])
    observation = Observation(1.0, "burst", Resource(topic="/toy"), Code.GENERAL_OK,
                              values={"burst": 10.0})
    out = mapper.start(0.0) + mapper.observations(1.0, [observation])
    [spec] = [s for s in out if isinstance(s, C_Monitored_Characteristic_Specification)]
    assert spec.A_unit == "msg"
    assert sorted(t.A_value for t in out if isinstance(t, C_Threshold)) == [1.0, 8.0, 12.0]


def test_the_plugin_observer_judges_values_in_diagnosis(plugins: None) -> None:
    model = parse_robot_model(ConfigNode.parse(MODEL, "model.yaml"))
    structure = TopicStructure(model)
    burst, hz = (ObservationSpec(t, Resource(topic="/toy")) for t in ("burst", "hz"))
    assert not is_rate_type("burst") and is_rate_type("hz")
    # a value observation blames the publisher, a rate observation also the topic itself
    assert structure.explain(burst).components == ("/toy_node",)
    assert structure.explain(hz).components == ("/toy", "/toy_node")


def test_the_plugin_source_runs_the_plugin_observer_end_to_end(plugins: None,
                                                               tmp_path: Path) -> None:
    sink = Collect()
    box = build(RunOptions(config=write(tmp_path, NATIVE), source="toy:", duration=5.0,
                           simulated_clock=True, live=False, diagnosis=False,
                           extra_sinks=[sink]))
    box.run()
    bursts = [o for o in sink.observations if o.observer == "burst"]
    assert len(bursts) == 5
    assert all(o.code is Code.GENERAL_OK for o in bursts[1:])
    assert {o.values["burst"] for o in bursts[1:]} == {10.0}


def test_a_source_is_refused_what_it_cannot_do(plugins: None, tmp_path: Path) -> None:
    config = write(tmp_path, NATIVE)
    for options in (RunOptions(config=config, source="toy:", faults="random", live=False),
                    RunOptions(config=config, source="toy:", ground_truth=tmp_path / "t.jsonl",
                               live=False)):
        with pytest.raises(ConfigError) as err:
            build(options)
        assert err.value.file == "--source"
