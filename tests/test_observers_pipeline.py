"""Observers built from a native file and run by the real pipeline over replayed events."""

from __future__ import annotations

from types import SimpleNamespace

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigNode
from blackbox.events import GraphSnapshot, MessageArrival, NodeInfo
from blackbox.model import Code
from blackbox.observe.build import build_observer
from blackbox.pipeline import Pipeline
from blackbox.sources.memory import MemorySource

CONFIG = """\
observers:
  - type: hz
    topic: /signal
    filter: {type: mean, window_size: 10}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.1, std_deviation: 0.02}}}
  - type: timeout
    topic: /signal
    timeout: 1.0
  - type: activated
    node: /generator
  - type: scores
    topic: /signal
    states:
      - {number: 1, name: ok, score: {value: {type: gauss, mean: 15, std_deviation: 0.5}}}
"""


def events() -> list:
    """/generator publishes 15.0 at 10 Hz until it dies at 3.0 s."""
    out: list = [GraphSnapshot(0.0, {"/generator": NodeInfo("/generator", True, pid=99)})]
    out += [MessageArrival(k * 0.1, "/signal", "/generator", 8, value=SimpleNamespace(data=15.0))
            for k in range(1, 30)]
    out.append(GraphSnapshot(3.0, {"/generator": NodeInfo("/generator", False, pid=99)}))
    return out


def test_a_dying_publisher_seen_by_every_observer() -> None:
    root = ConfigNode.parse(CONFIG, "robot.yaml")
    observers = [build_observer(e) for e in root["observers"].list()]
    pipeline = Pipeline(MemorySource(events()), observers)
    pipeline.start()
    seen: list = []
    for step in range(1, 25):  # 0.25 s steps up to 6 s
        seen += pipeline.step(step * 0.25)
    pipeline.close()

    def codes(observer: str) -> list[tuple[float, Code]]:
        return [(o.time, o.code) for o in seen if o.observer == observer]

    hz = codes("hz")
    assert hz[:3] == [(1.0, Code.GENERAL_OK), (2.0, Code.GENERAL_OK), (3.0, Code.GENERAL_OK)]
    # last message at 2.9: at 4.0 the provisional period 1.1 s lifts the mean of 10 to 0.2
    assert hz[3] == (4.0, Code.NO_STATE_FITS)
    # checked every 0.25 s, reported every 1 s and at once when the code changes
    assert codes("timeout") == [(0.25, Code.GENERAL_OK), (1.25, Code.GENERAL_OK),
                                (2.25, Code.GENERAL_OK), (3.25, Code.GENERAL_OK),
                                (4.0, Code.TIMEOUT), (5.0, Code.TIMEOUT), (6.0, Code.TIMEOUT)]
    assert codes("activated") == [(1.0, Code.GENERAL_OK), (2.0, Code.GENERAL_OK),
                                  (3.0, Code.GENERAL_ERROR), (4.0, Code.GENERAL_ERROR),
                                  (5.0, Code.GENERAL_ERROR), (6.0, Code.GENERAL_ERROR)]
    scores = codes("scores")
    assert all(code == Code.GENERAL_OK for _, code in scores)
