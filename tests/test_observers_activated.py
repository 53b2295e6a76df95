"""activated observer: a node is running when it answers itself, not when it is registered."""

from __future__ import annotations

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import GraphSnapshot, Interest, NodeInfo
from blackbox.model import Code, Resource
from blackbox.observe.base import OBSERVERS


def build(extra: str = ""):
    text = f"type: activated\nnode: /camera\n{extra}\n"
    return OBSERVERS["activated"].build(ConfigNode.parse(text, "t.yaml"))


def graph(t: float, *nodes: NodeInfo) -> GraphSnapshot:
    return GraphSnapshot(t, {n.name: n for n in nodes})


def test_alive_node_is_ok() -> None:
    act = build()
    act.on_graph(graph(0.5, NodeInfo("/camera", True, pid=4242), NodeInfo("/base", True)))
    [obs] = act.evaluate(1.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.observer == "activated"
    assert obs.resource == Resource(node="/camera")
    assert obs.message == "node /camera is running (pid 4242)"
    assert obs.values == {"alive": 1.0}


def test_killed_node_still_registered_is_an_error() -> None:
    act = build()
    act.on_graph(graph(0.5, NodeInfo("/camera", True)))
    assert act.evaluate(1.0)[0].code == Code.GENERAL_OK
    act.on_graph(graph(1.5, NodeInfo("/camera", False)))
    [obs] = act.evaluate(2.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message == "node /camera is not running (registered but not answering)"
    assert obs.values == {"alive": 0.0}


def test_node_absent_from_the_graph_is_an_error() -> None:
    act = build()
    act.on_graph(graph(0.5, NodeInfo("/base", True)))
    [obs] = act.evaluate(1.0)
    assert obs.code == Code.GENERAL_ERROR
    assert obs.message == "node /camera is not running (not in the graph)"


def test_not_available_before_the_first_snapshot() -> None:
    act = build()
    [obs] = act.evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for the first graph snapshot"


def test_start_up_time_gives_a_starting_node_grace() -> None:
    act = build("start_up_time: 5")
    act.on_graph(graph(10.0, NodeInfo("/base", True)))
    [obs] = act.evaluate(12.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == ("node /camera is not running yet (not in the graph); start-up time "
                           "5 s, 2 s passed")
    [obs] = act.evaluate(15.5)
    assert obs.code == Code.GENERAL_ERROR


def test_start_up_time_counts_from_the_first_evaluation_without_snapshots() -> None:
    act = build("start_up_time: 5")
    act.evaluate(1.0)
    act.on_graph(graph(3.0))
    assert act.evaluate(5.0)[0].code == Code.NOT_AVAILABLE
    assert act.evaluate(6.0)[0].code == Code.GENERAL_ERROR


def test_a_running_node_is_ok_during_start_up() -> None:
    act = build("start_up_time: 5")
    act.on_graph(graph(0.0, NodeInfo("/camera", True)))
    assert act.evaluate(1.0)[0].code == Code.GENERAL_OK


def test_reacts_at_the_next_evaluation_after_a_snapshot() -> None:
    act = build()
    act.on_graph(graph(0.0, NodeInfo("/camera", True)))
    act.on_graph(graph(0.4, NodeInfo("/camera", False)))
    act.on_graph(graph(0.8, NodeInfo("/camera", True, pid=7)))
    [obs] = act.evaluate(1.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.message.endswith("(pid 7)")


def test_interest_and_describe() -> None:
    act = build("start_up_time: 2.5\nevery: 0.5")
    assert act.interest() == Interest(nodes=frozenset({"/camera"}))
    assert act.interval == 0.5
    assert act.describe() == "activated /camera: node alive, start-up time 2.5 s, every 0.5 s"


@pytest.mark.parametrize(("text", "line", "message"), [
    ("type: activated\n", 1, "missing required key 'node'"),
    ("type: activated\nnode: /a\nstart_up_time: -1\n", 3, "must be >= 0"),
    ("type: activated\nnode: /a\nstartup_time: 1\n", 3, "did you mean 'start_up_time'?"),
    ("type: activated\nnode: [/a, /b]\n", 2, "expected a single value"),
])
def test_config_errors(text: str, line: int, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        OBSERVERS["activated"].build(ConfigNode.parse(text, "t.yaml"))
    assert err.value.line == line
    assert message in err.value.message
