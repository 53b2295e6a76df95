"""Loading tug_diagnosis model files and the clauses they imply."""

from __future__ import annotations

from pathlib import Path

import pytest

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.diagnose.robot_model import (
    NodeSpec,
    ObservationSpec,
    RobotModel,
    TopicStructure,
    load_robot_model,
    parse_robot_model,
)
from blackbox.model import Code, Observation, Resource

SHARED = Path(__file__).resolve().parents[1] / "data" / "shared"
TUG_FILES = sorted((SHARED / "compat/tug_diagnosis").glob("*.yaml"))
THESIS_MODEL = SHARED / "reference/thesis-setup/diagnosis_model.yaml"


@pytest.mark.skipif(not TUG_FILES, reason="shared tug_diagnosis files missing")
@pytest.mark.parametrize("path", TUG_FILES, ids=lambda p: p.name)
def test_every_shared_tug_diagnosis_file_loads(path: Path):
    model = load_robot_model(path)
    assert [n.name for n in model.nodes] == ["node1", "node2", "node3"]
    assert model.node("node2") == NodeSpec("node2", ("/topic2",), ("/topic1",))
    assert ObservationSpec("timing", Resource(topic="/topic1", topic_b="/topic2")) in (
        model.observations)
    engine = DiagnosisEngine(model)
    assert set(engine.model.components) == {"node1", "node2", "node3", "/topic1", "/topic2",
                                            "/topic3"}


@pytest.mark.skipif(not THESIS_MODEL.is_file(), reason="shared thesis setup missing")
def test_thesis_model_structure():
    model = load_robot_model(THESIS_MODEL)
    assert model.publishers("/signal") == ("/Signal_generator",)
    assert len(model.observations) == 10
    ex = TopicStructure(model).explain(ObservationSpec("hz", Resource(topic="/signal")))
    assert set(ex.components) == {"/signal", "/Signal_generator"}
    assert set(ex.inputs) == {"/usb_cam/image_raw", "/audio"}
    value = TopicStructure(model).explain(ObservationSpec("scores", Resource(topic="/signal")))
    assert set(value.components) == {"/Signal_generator"}  # transports do not change values


def parse(text: str):
    return parse_robot_model(ConfigNode.parse(text, "model.yaml"))


@pytest.mark.parametrize(("text", "line", "message"), [
    ("nodes:\n  - name: a\n    pub_topic: [/x]\nobservations:\n  - type: hzz\n    topics: [/x]\n",
     5, "did you mean 'hz'"),
    ("nodes:\n  - name: a\n    pub_topic: [/x]\nobservations:\n  - type: hz\n    topics: [/y]\n",
     6, "'/y' is neither published nor subscribed"),
    ("nodes:\n  - name: a\n  - name: a\n", 3, "defined twice"),
    ("nodes:\n  - name: a\n    pubtopic: [/x]\n", 3, "did you mean 'pub_topic'"),
    ("nodes:\n  - name: a\nobservations:\n  - type: activated\n    nodes: [b]\n", 5,
     "unknown node 'b'"),
    ("nodes:\n  - name: a\n    pub_topic: [/x, /y]\nobservations:\n  - type: timing\n"
     "    topics: [/x]\n", 6, "exactly two topics"),
])
def test_bad_models_name_file_and_line(text: str, line: int, message: str):
    with pytest.raises(ConfigError) as err:
        parse(text)
    assert err.value.file == "model.yaml"
    assert err.value.line == line
    assert message in str(err.value)


def test_hardware_behind_a_driver_is_a_component():
    model = parse("nodes:\n  - name: /usb_cam\n    pub_topic: [/img]\n    hardware: [camera]\n"
                  "observations:\n  - type: activated\n    nodes: [/usb_cam]\n"
                  "  - type: timeout\n    topics: [/img]\n")
    engine = DiagnosisEngine(model)
    obs = [Observation(1.0, "activated", Resource(node="/usb_cam"), Code.GENERAL_OK),
           Observation(1.0, "timeout", Resource(topic="/img"), Code.TIMEOUT)]
    d = engine.update(1.0, obs)
    assert d is not None
    # The camera first: its driver answers (a passing observation), the hardware has none.
    assert [set(c) for c in d.candidates] == [{"camera"}, {"/usb_cam"}, {"/img"}]
    assert "hardware camera" in engine.explain(d.candidates, d.failed, True)


def test_feedback_loop_of_healthy_nodes_explains_nothing_by_itself():
    # a -> /x -> b -> /y -> a : a symptom on /y needs a faulty component in the loop.
    model = RobotModel((NodeSpec("a", ("/x",), ("/y",)), NodeSpec("b", ("/y",), ("/x",))),
                       (ObservationSpec("hz", Resource(topic="/y")),))
    engine = DiagnosisEngine(model)
    d = engine.update(1.0, [Observation(1.0, "hz", Resource(topic="/y"), Code.NO_STATE_FITS)])
    assert d is not None
    assert {frozenset(c) for c in d.candidates} == {frozenset({x}) for x in
                                                    ("a", "b", "/x", "/y")}


def test_publisher_group_limits_the_suspects():
    model = RobotModel((NodeSpec("a", ("/x",)), NodeSpec("b", ("/x",))),
                       (ObservationSpec("hz", Resource(topic="/x", publishers=("b",))),))
    engine = DiagnosisEngine(model)
    d = engine.update(1.0, [Observation(1.0, "hz", Resource(topic="/x", publishers=("b",)),
                                        Code.NO_STATE_FITS)])
    assert d is not None and [set(c) for c in d.candidates] == [{"b"}, {"/x"}]
