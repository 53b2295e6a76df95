"""Failure modes and how they propagate: a silent input explains a silent output only while
the node is not seen publishing without it, and a wrong output value is explained by an input
only through a wrong input value. This is what isolates two simultaneous faults, one on a
driver and one on the node downstream of it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

from blackbox.app import RunOptions, build
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.diagnose.live import DiagnosisSettings, LiveDiagnoser
from blackbox.diagnose.robot_model import (
    Edge,
    NodePropagation,
    NodeSpec,
    ObservationSpec,
    Propagation,
    RobotModel,
    load_robot_model,
)
from blackbox.events import GraphSnapshot, NodeInfo, TopicInfo
from blackbox.model import Code, Diagnosis, Observation, Resource
from blackbox.sinks import SinkBase
from conftest import SHARED
from diagnosis_support import observations

THESIS_MODEL = SHARED / "reference/thesis-setup/diagnosis_model.yaml"
SRC = Path(__file__).resolve().parents[1] / "src" / "blackbox"
pytestmark = pytest.mark.skipif(not THESIS_MODEL.is_file(), reason="shared thesis setup missing")

SG = "/Signal_generator"
CAMERA_EDGE = Edge(SG, "/signal", "/usb_cam/image_raw")
KILL_USB_CAM = {("activated", "/usb_cam"), ("hz", "/usb_cam/image_raw"),
                ("timeout", "/usb_cam/image_raw")}
SIGNAL_SILENT = {("hz", "/signal"), ("timeout", "/signal")}


def thesis_engine(**kw: object) -> DiagnosisEngine:
    return DiagnosisEngine.from_model_file(THESIS_MODEL, **kw)


def candidates(engine: DiagnosisEngine) -> list[set[str]]:
    return [set(c) for c in engine.current().candidates]


def feed(engine: DiagnosisEngine, times: Sequence[float], failed: set[tuple[str, str]],
         unknown: set[tuple[str, str]] = frozenset()) -> None:
    for t in times:
        engine.update(t, observations(engine, failed, unknown, t))


# ---- values ----------------------------------------------------------------------------------

def test_dead_camera_and_wrong_signal_value_yield_the_pair():
    # The camera topic is seen silent (its time-out failed), so it carries no values and
    # cannot make /signal wrong: the wrong value needs the generator, or the audio driver,
    # whose values nothing judges.
    engine = thesis_engine()
    feed(engine, [1.0], KILL_USB_CAM | {("scores", "/signal")})
    assert candidates(engine) == [{"/usb_cam", SG}, {"/usb_cam", "/audio_capture"}]


def test_an_off_rate_camera_may_also_send_wrong_values():
    # Off rate is not silent: a faulty camera still sends messages, and nothing judges
    # their values, so the camera alone explains both symptoms.
    engine = thesis_engine()
    feed(engine, [1.0], {("hz", "/usb_cam/image_raw"), ("scores", "/signal")})
    got = candidates(engine)
    assert got[0] == {"/usb_cam"}
    assert {SG, "/usb_cam/image_raw"} in got


def test_dead_camera_and_wrong_signal_value_yield_the_pair_when_camera_values_are_right():
    # With a value observer on the camera topic that stays OK, the wrong signal value needs
    # the generator (a silent input explains wrong values only with value_from_rate).
    model = load_robot_model(THESIS_MODEL)
    model = RobotModel(model.nodes, (*model.observations, ObservationSpec(
        "scores", Resource(topic="/usb_cam/image_raw"))))
    engine = DiagnosisEngine(model)
    feed(engine, [1.0], KILL_USB_CAM | {("scores", "/signal")})
    assert candidates(engine) == [{"/usb_cam", SG}, {"/usb_cam", "/audio_capture"}]
    stale = DiagnosisEngine(model, propagation=Propagation(value_from_rate=True))
    feed(stale, [1.0], KILL_USB_CAM | {("scores", "/signal")})
    assert candidates(stale) == [{"/usb_cam"}]


def test_value_from_rate_lets_a_dead_input_explain_a_wrong_value():
    engine = thesis_engine(propagation=Propagation(value_from_rate=True))
    feed(engine, [1.0], KILL_USB_CAM | {("scores", "/signal")})
    assert candidates(engine) == [{"/usb_cam"}]
    per_node = thesis_engine(propagation=Propagation(
        nodes={SG: NodePropagation(value_from_rate=True)}))
    feed(per_node, [1.0], KILL_USB_CAM | {("scores", "/signal")})
    assert candidates(per_node) == [{"/usb_cam"}]


def chain(*observed: tuple[str, str]) -> DiagnosisEngine:
    """a -> /x -> b -> /y -> c -> /z with the given (type, topic) observations."""
    nodes = (NodeSpec("a", ("/x",)), NodeSpec("b", ("/y",), ("/x",)),
             NodeSpec("c", ("/z",), ("/y",)))
    return DiagnosisEngine(RobotModel(nodes, tuple(ObservationSpec(k, Resource(topic=t))
                                                   for k, t in observed)))


def chain_update(engine: DiagnosisEngine, failed: set[tuple[str, str]]) -> list[set[str]]:
    obs = [Observation(1.0, s.type, s.resource,
                       Code.NO_STATE_FITS if (s.type, s.resource.topic) in failed
                       else Code.GENERAL_OK) for s in engine.model.observations]
    d = engine.update(1.0, obs)
    assert d is not None
    return [set(c) for c in d.candidates]


def test_a_wrong_value_propagates_through_observed_wrong_values():
    observed = (("hz", "/x"), ("scores", "/x"), ("hz", "/y"), ("scores", "/y"))
    assert chain_update(chain(*observed), {("scores", "/x"), ("scores", "/y")}) == [{"a"}]
    assert chain_update(chain(*observed), {("scores", "/y")}) == [{"b"}]


def test_a_wrong_value_upstream_does_not_explain_a_rate_failure_downstream():
    observed = (("hz", "/x"), ("scores", "/x"), ("hz", "/y"), ("scores", "/y"))
    got = chain_update(chain(*observed), {("scores", "/x"), ("hz", "/y")})
    assert got == [{"a", "b"}, {"a", "/y"}]


def test_unobserved_topics_keep_every_upstream_component_a_suspect():
    # Equal priors: the component closer to the symptom ranks first.
    assert chain_update(chain(("scores", "/z")), {("scores", "/z")}) == [{"c"}, {"b"}, {"a"}]
    assert chain_update(chain(("hz", "/z")), {("hz", "/z")}) == [
        {"c"}, {"b"}, {"a"}, {"/z"}, {"/y"}, {"/x"}]


def test_a_rate_observer_says_nothing_about_values_upstream():
    # /x and /y are watched for their rate only: a wrong value seen on /z may come from a
    # driver publishing wrong values at the right rate, so a and b stay suspects.
    observed = (("hz", "/x"), ("hz", "/y"), ("scores", "/z"))
    assert chain_update(chain(*observed), {("scores", "/z")}) == [{"c"}, {"b"}, {"a"}]
    with_values = (*observed, ("scores", "/y"))
    assert chain_update(chain(*with_values), {("scores", "/z")}) == [{"c"}]


# ---- rates -----------------------------------------------------------------------------------

def test_before_anything_is_learnt_a_silent_input_explains_a_silent_output():
    engine = thesis_engine()
    feed(engine, [1.0], KILL_USB_CAM | SIGNAL_SILENT)
    assert candidates(engine) == [{"/usb_cam"}]


def test_publishing_at_rate_without_an_input_for_learn_after_seconds_cuts_the_edge():
    engine = thesis_engine()
    feed(engine, [1.0, 2.0, 3.0], KILL_USB_CAM)
    assert engine.independent == frozenset()  # 2 s of evidence, 3 s needed
    feed(engine, [4.0], KILL_USB_CAM)
    assert engine.independent == {CAMERA_EDGE}
    assert not engine.depends(CAMERA_EDGE)
    assert engine.depends(Edge(SG, "/signal", "/audio"))  # /audio was never silent
    feed(engine, [5.0], KILL_USB_CAM | SIGNAL_SILENT)
    assert candidates(engine) == [{"/usb_cam", SG}, {"/usb_cam", "/signal"}]


def test_interrupted_evidence_starts_again():
    engine = thesis_engine()
    feed(engine, [1.0, 2.0], KILL_USB_CAM)
    feed(engine, [3.0], set())
    feed(engine, [4.0, 5.0, 6.0], KILL_USB_CAM)
    assert engine.independent == frozenset()
    feed(engine, [7.0], KILL_USB_CAM)
    assert engine.independent == {CAMERA_EDGE}


def test_a_dead_publisher_is_a_silent_topic_without_a_timeout_observer():
    engine = thesis_engine()
    feed(engine, [1.0, 4.0], {("activated", "/usb_cam"), ("hz", "/usb_cam/image_raw")},
         unknown={("timeout", "/usb_cam/image_raw")})
    assert engine.independent == {CAMERA_EDGE}


def test_no_learning_while_the_output_rate_is_unknown_or_wrong():
    unknown_rate = thesis_engine()
    feed(unknown_rate, [1.0, 5.0], KILL_USB_CAM, unknown={("hz", "/signal")})
    silent_too = thesis_engine()
    feed(silent_too, [1.0, 5.0], KILL_USB_CAM | SIGNAL_SILENT)
    slow_input = thesis_engine()
    feed(slow_input, [1.0, 5.0], {("hz", "/usb_cam/image_raw")})  # off rate, not silent
    assert (unknown_rate.independent, silent_too.independent, slow_input.independent) == (
        frozenset(), frozenset(), frozenset())


def test_configured_rate_propagation_per_node():
    never = thesis_engine(propagation=Propagation(nodes={SG: NodePropagation(rate="never")}))
    feed(never, [1.0], KILL_USB_CAM | SIGNAL_SILENT)
    assert candidates(never) == [{"/usb_cam", SG}, {"/usb_cam", "/signal"}]
    always = thesis_engine(propagation=Propagation(rate="always"))
    feed(always, [1.0, 2.0, 5.0, 9.0], KILL_USB_CAM)
    assert always.independent == frozenset()
    feed(always, [10.0], KILL_USB_CAM | SIGNAL_SILENT)
    assert candidates(always) == [{"/usb_cam"}]
    quick = thesis_engine(propagation=Propagation(learn_after=0.0))
    feed(quick, [1.0], KILL_USB_CAM)
    assert quick.independent == {CAMERA_EDGE}


def test_propagation_rejects_unknown_modes():
    with pytest.raises(ValueError, match="learn, always, never"):
        Propagation(rate="sometimes")


# ---- configuration and the live diagnoser ----------------------------------------------------

def settings(text: str, base: Path) -> DiagnosisSettings:
    return DiagnosisSettings.from_config(ConfigNode.parse(text, "config.yaml")["diagnosis"],
                                         base)


def test_diagnosis_section_configures_propagation(tmp_path: Path):
    s = settings("diagnosis:\n  propagation:\n    rate: never\n    learn_after: 5\n"
                 "    value_from_rate: true\n    nodes:\n"
                 "      /Signal_generator: {rate: learn, value_from_rate: false}\n", tmp_path)
    assert s.propagation == Propagation("never", True, 5.0,
                                        {SG: NodePropagation("learn", False)})
    assert (s.propagation.rate_of(SG), s.propagation.rate_of("/usb_cam")) == ("learn", "never")
    assert not s.propagation.value_from_rate_of(SG)
    assert s.propagation.value_from_rate_of("/usb_cam")
    assert settings("diagnosis:\n  enabled: true\n", tmp_path).propagation == Propagation()


@pytest.mark.parametrize(("text", "line", "message"), [
    ("diagnosis:\n  propagation:\n    rate: sometimes\n", 3, "expected one of learn, always"),
    ("diagnosis:\n  propagation:\n    learn_after: -1\n", 3, "must be >= 0"),
    ("diagnosis:\n  propagation:\n    nodes:\n      /a: {rates: never}\n", 4,
     "did you mean 'rate'"),
    ("diagnosis:\n  propagation:\n    value_from_rate: 1\n", 3, "expected true or false"),
    ("diagnosis:\n  propagaton: {}\n", 2, "did you mean 'propagation'"),
])
def test_bad_propagation_settings_name_the_line(tmp_path: Path, text: str, line: int,
                                                message: str):
    with pytest.raises(ConfigError) as err:
        settings(text, tmp_path)
    assert err.value.line == line
    assert message in str(err.value)


@dataclass
class FakeObserver:
    """Stands in for an observer: the model only reads these two attributes."""

    type_name: str
    resource: Resource


def graph(extra_subscriber: bool = False) -> GraphSnapshot:
    nodes = {n: NodeInfo(n, True) for n in ("/usb_cam", "/audio_capture", SG, "/viewer")}
    signal_subs = ("/viewer",) if extra_subscriber else ()
    topics = {
        "/usb_cam/image_raw": TopicInfo("/usb_cam/image_raw", "sensor_msgs/Image",
                                        ("/usb_cam",), (SG,)),
        "/audio": TopicInfo("/audio", "audio_common_msgs/AudioData", ("/audio_capture",),
                            (SG,)),
        "/signal": TopicInfo("/signal", "std_msgs/Float64", (SG,), signal_subs),
    }
    return GraphSnapshot(0.0, nodes, topics)


def test_learnt_edges_survive_a_new_graph():
    observers = [FakeObserver(s.type, s.resource)
                 for s in load_robot_model(THESIS_MODEL).observations]
    live = LiveDiagnoser(observers, DiagnosisSettings())
    live.on_graph(graph())
    first = live.engine
    assert first is not None
    for t in (1.0, 2.0, 5.0):
        live.update(t, observations(first, KILL_USB_CAM, t=t))
    assert first.independent == {CAMERA_EDGE}
    live.on_graph(graph(extra_subscriber=True))
    assert live.engine is not first and live.engine.independent == {CAMERA_EDGE}
    d = live.update(6.0, observations(live.engine, KILL_USB_CAM | SIGNAL_SILENT, t=6.0))
    assert d is not None and set(d.candidates[0]) == {"/usb_cam", SG}


# ---- on the simulated thesis robot -----------------------------------------------------------

class Diagnoses(SinkBase):
    def __init__(self) -> None:
        self.records: list[Diagnosis] = []

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        self.records.append(diagnosis)


def run(tmp_path: Path, faults: str, duration: float, source: str = "sim:thesis"
        ) -> list[Diagnosis]:
    schedule = tmp_path / "faults.yaml"
    schedule.write_text("faults:\n" + faults)
    config = tmp_path / "config.yaml"
    config.write_text((SRC / "configs" / "thesis.yaml").read_text())
    sink = Diagnoses()
    build(RunOptions(config=config, source=source, duration=duration, simulated_clock=True,
                     faults=str(schedule), live=False, extra_sinks=[sink])).run()
    return sink.records


def last_before(records: Sequence[Diagnosis], end: float) -> Diagnosis:
    return [d for d in records if d.time < end][-1]


def test_sim_dead_camera_and_wrong_signal_value(tmp_path: Path):
    records = run(tmp_path, "  - {kind: kill, component: /usb_cam, start: 20, end: 40}\n"
                  "  - {kind: offset, component: /signal, start: 25, end: 40, value: 3.0}\n",
                  42.0)
    assert last_before(records, 40.0).candidates[0] == {"/usb_cam", SG}


def test_sim_dead_camera_then_stalled_signal(tmp_path: Path):
    # The generator keeps publishing for 6 s after the camera died: it does not need it.
    records = run(tmp_path, "  - {kind: kill, component: /usb_cam, start: 20, end: 40}\n"
                  "  - {kind: stall, component: /signal, start: 26, end: 40}\n", 42.0)
    assert last_before(records, 26.0).candidates == ({"/usb_cam"},)
    assert last_before(records, 40.0).candidates[0] == {"/usb_cam", SG}


def test_sim_generator_that_needs_its_inputs_is_not_blamed(tmp_path: Path):
    topology = tmp_path / "robot.yaml"
    topology.write_text((SRC / "sources" / "sim" / "thesis.yaml").read_text().replace(
        "    # requires: {topics:", "    requires: {topics:"))
    records = run(tmp_path, "  - {kind: kill, component: /usb_cam, start: 20, end: 40}\n",
                  42.0, source=f"sim:{topology}")
    settled = last_before(records, 40.0)
    assert {o.resource.topic for o in settled.failed} >= {"/signal"}  # it did stop
    assert settled.candidates == ({"/usb_cam"},)
