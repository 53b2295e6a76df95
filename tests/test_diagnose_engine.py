"""DiagnosisEngine on the thesis robot (thesis Fig. 6.7/6.8 model)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.diagnose.robot_model import load_robot_model
from blackbox.events import GraphSnapshot, NodeInfo, TopicInfo
from blackbox.model import Code, Observation, Resource
from diagnosis_support import observations

SHARED = Path(__file__).resolve().parents[1] / "data" / "shared"
THESIS_MODEL = SHARED / "reference/thesis-setup/diagnosis_model.yaml"
pytestmark = pytest.mark.skipif(not THESIS_MODEL.is_file(), reason="shared thesis setup missing")

KILL_USB_CAM = {("activated", "/usb_cam"), ("hz", "/usb_cam/image_raw"),
                ("timeout", "/usb_cam/image_raw")}


def diagnose(failed: set[tuple[str, str]], unknown=frozenset(), **kw) -> list[set[str]]:
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL, **kw)
    d = engine.update(1.0, observations(engine, failed, unknown))
    assert d is not None
    return [set(c) for c in d.candidates]


def test_killing_usb_cam_blames_only_the_driver():
    assert diagnose(KILL_USB_CAM) == [{"/usb_cam"}]


def test_wrong_signal_value_blames_the_signal_generator():
    # hz and timeout on /usb_cam/image_raw and /audio are fine: their publishers are cleared.
    assert diagnose({("scores", "/signal")}) == [{"/Signal_generator"}]


def test_without_evidence_on_inputs_upstream_nodes_stay_suspects():
    got = diagnose({("scores", "/signal")}, unknown={("hz", "/audio"), ("timeout", "/audio")})
    assert got[0] == {"/Signal_generator"}
    assert {"/audio_capture"} in got and {"/usb_cam"} not in got


def test_two_simultaneous_faults_yield_the_pair():
    both_dead = KILL_USB_CAM | {("activated", "/audio_capture"), ("hz", "/audio"),
                                ("timeout", "/audio")}
    assert diagnose(both_dead) == [{"/usb_cam", "/audio_capture"}]
    camera_dead_audio_slow = KILL_USB_CAM | {("hz", "/audio")}
    got = diagnose(camera_dead_audio_slow)
    assert got[0] == {"/usb_cam", "/audio_capture"}
    assert got[1:] == [{"/usb_cam", "/audio"}]  # the topic ranks after the node


def test_silent_topic_of_a_live_node_ranks_node_before_topic():
    assert diagnose({("hz", "/usb_cam/image_raw"), ("timeout", "/usb_cam/image_raw")}) == [
        {"/usb_cam"}, {"/usb_cam/image_raw"}]


def test_priors_reorder_equal_cardinality_candidates():
    got = diagnose({("hz", "/usb_cam/image_raw")}, priors={"/usb_cam/image_raw": 0.5})
    assert got == [{"/usb_cam/image_raw"}, {"/usb_cam"}]


def test_priors_must_be_probabilities():
    with pytest.raises(ValueError, match="prior"):
        DiagnosisEngine.from_model_file(THESIS_MODEL, priors={"/usb_cam": 1.5})


def test_update_reports_only_changes_and_reuses_results():
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL)
    healthy = engine.update(0.0, observations(engine, set(), t=0.0))
    assert healthy is not None and healthy.candidates == () and healthy.failed == ()
    assert engine.update(1.0, observations(engine, set(), t=1.0)) is None
    d = engine.update(2.0, observations(engine, KILL_USB_CAM, t=2.0))
    assert d is not None and d.time == 2.0
    assert {o.observer for o in d.failed} == {"activated", "hz", "timeout"}
    assert "/usb_cam" in d.explanation and "faulty" in d.explanation
    assert engine.current() is d
    assert engine.update(3.0, observations(engine, KILL_USB_CAM, t=3.0)) is None
    engine.update(4.0, observations(engine, set(), t=4.0))
    calls = engine.checker.calls
    again = engine.update(5.0, observations(engine, KILL_USB_CAM, t=5.0))
    assert again is not None and again.candidates == d.candidates
    assert engine.checker.calls == calls  # answered from the result cache


def test_conflicts_are_reused_when_their_observations_still_hold():
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL)
    engine.update(1.0, observations(engine, {("activated", "/usb_cam")}))
    assert frozenset({"/usb_cam"}) in engine._conflicts
    engine.update(2.0, observations(engine, KILL_USB_CAM))
    assert [set(c) for c in engine.current().candidates] == [{"/usb_cam"}]


def test_not_available_is_no_evidence():
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL)
    obs = observations(engine, set(), unknown={("activated", "/usb_cam")})
    d = engine.update(1.0, obs)
    assert d is not None and d.failed == () and d.candidates == ()


def test_undeclared_observation_extends_the_model():
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL)
    d = engine.update(1.0, [Observation(1.0, "resources", Resource(node="/extra"),
                                        Code.NO_STATE_FITS)])
    assert d is not None and [set(c) for c in d.candidates] == [{"/extra"}]


@dataclass
class FakeObserver:
    """Stands in for an observer: the model only reads these two attributes."""

    type_name: str
    resource: Resource


def thesis_graph() -> GraphSnapshot:
    nodes = {n: NodeInfo(n, True) for n in ("/usb_cam", "/audio_capture", "/Signal_generator",
                                            "/rosout", "/blackbox")}
    topics = {
        "/usb_cam/image_raw": TopicInfo("/usb_cam/image_raw", "sensor_msgs/Image",
                                        ("/usb_cam",), ("/Signal_generator", "/blackbox")),
        "/audio": TopicInfo("/audio", "audio_common_msgs/AudioData", ("/audio_capture",),
                            ("/Signal_generator", "/blackbox")),
        "/signal": TopicInfo("/signal", "std_msgs/Float64", ("/Signal_generator",),
                             ("/blackbox",)),
        "/rosout": TopicInfo("/rosout", "rosgraph_msgs/Log",
                             ("/usb_cam", "/audio_capture", "/Signal_generator"), ("/rosout",)),
        "/rosout_agg": TopicInfo("/rosout_agg", "rosgraph_msgs/Log", ("/rosout",), ()),
    }
    return GraphSnapshot(0.0, nodes, topics)


def test_model_derived_from_graph_equals_the_yaml_model():
    yaml_model = load_robot_model(THESIS_MODEL)
    observers = [FakeObserver(s.type, s.resource) for s in yaml_model.observations]
    engine = DiagnosisEngine.from_graph(thesis_graph(), observers)
    assert engine.model == yaml_model
    d = engine.update(1.0, observations(engine, KILL_USB_CAM))
    assert d is not None and [set(c) for c in d.candidates] == [{"/usb_cam"}]
