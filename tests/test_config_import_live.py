"""An imported configuration is validated and applied to a running black box without a
restart; one that cannot be applied leaves the running observers as they were."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest

from blackbox.app import DEFAULT_CONFIG, RunOptions, apply_config, build
from blackbox.config.node import ConfigError
from blackbox.model import Observation
from blackbox.sinks import SinkBase


class Collect(SinkBase):
    def __init__(self) -> None:
        self.observations: list[Observation] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self.observations.extend(observations)


def running(tmp_path: Path):
    sink = Collect()
    box = build(RunOptions(config=DEFAULT_CONFIG, simulated_clock=True, live=False,
                           record=tmp_path / "bb.db", extra_sinks=[sink]))
    box.pipeline.start()
    for t in range(1, 11):
        box.pipeline.step(float(t))
    return box, sink


def test_new_thresholds_apply_without_restart(tmp_path: Path) -> None:
    box, sink = running(tmp_path)
    assert not any(o.faulty for o in sink.observations)
    stricter = DEFAULT_CONFIG.read_text().replace(
        "score: {value: {type: gauss, mean: 15.0, std_deviation: 0.5}}",
        "score: {value: {type: gauss, mean: 20.0, std_deviation: 0.5}}")
    apply_config(box.pipeline, stricter, "imported version 2")
    for t in range(11, 14):
        box.pipeline.step(float(t))
    box.pipeline.close()
    after = [o for o in sink.observations if o.time > 10.0]
    assert {o.key()[0] for o in after if o.faulty} == {"scores"}
    assert any(o.observer == "recorder" for o in after), "self-monitoring survives the swap"


def test_a_configuration_needing_new_topics_is_rejected_and_nothing_changes(tmp_path: Path
                                                                             ) -> None:
    box, _ = running(tmp_path)
    before = list(box.pipeline.observers)
    other = "observers:\n  - {type: timeout, topic: /lidar, timeout: 1.0}\n"
    with pytest.raises(ValueError, match="/lidar"):
        apply_config(box.pipeline, other, "imported version 2")
    with pytest.raises(ConfigError, match="window_size"):
        apply_config(box.pipeline, "observers:\n  - {type: hz, topic: /audio, filter: "
                     "{type: mean, window_size: 0}}\n", "imported version 3")
    assert box.pipeline.observers == before
    box.pipeline.close()
