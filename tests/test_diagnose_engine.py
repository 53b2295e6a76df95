"""DiagnosisEngine on the thesis robot (thesis Fig. 6.7/6.8 model)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.diagnose.robot_model import ObservationSpec, RobotModel, load_robot_model
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


def test_wrong_signal_value_keeps_the_unobserved_inputs_open():
    # Only rate observers watch /usb_cam/image_raw and /audio: they say nothing about the
    # values there, so a driver sending wrong values at the right rate explains the symptom
    # as well as the generator does. The generator ranks first (closest to the symptom).
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL)
    d = engine.update(1.0, observations(engine, {("scores", "/signal")}))
    assert d is not None
    assert [set(c) for c in d.candidates] == [{"/Signal_generator"}, {"/audio_capture"},
                                              {"/usb_cam"}]
    assert ("do not tell node /Signal_generator apart from 2 other explanations of the same "
            "size (node /audio_capture; node /usb_cam)") in d.explanation
    assert "the values of /audio, /usb_cam/image_raw" in d.explanation
    assert "No other explanation" not in d.explanation


def test_a_value_observer_that_is_ok_clears_the_upstream_driver():
    # The same robot with a value observer on the camera topic that sees nothing wrong.
    model = load_robot_model(THESIS_MODEL)
    model = RobotModel(model.nodes, (*model.observations, ObservationSpec(
        "scores", Resource(topic="/usb_cam/image_raw"))))
    engine = DiagnosisEngine(model)
    d = engine.update(1.0, observations(engine, {("scores", "/signal")}))
    assert d is not None
    assert [set(c) for c in d.candidates] == [{"/Signal_generator"}, {"/audio_capture"}]
    unknown = engine.update(2.0, observations(engine, {("scores", "/signal")}, t=2.0,
                                              unknown={("scores", "/usb_cam/image_raw")}))
    assert unknown is not None and {"/usb_cam"} in [set(c) for c in unknown.candidates]


def test_a_unique_explanation_says_so():
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL)
    d = engine.update(1.0, observations(engine, KILL_USB_CAM))
    assert d is not None and d.complete
    assert d.explanation.endswith("No other explanation of the same or smaller size exists.")


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


def test_a_hand_written_configuration_on_a_new_robot_keeps_the_driver_a_suspect():
    """The issue's case: a model derived from the live graph, a rate observer on the
    driver's topic and a value observer on the downstream node's output. The driver sends
    wrong values at the right rate: only the downstream value observer fails, and the
    driver must be among the diagnoses."""
    nodes = {n: NodeInfo(n, True) for n in ("/imu_driver", "/estimator", "/blackbox")}
    topics = {
        "/imu": TopicInfo("/imu", "sensor_msgs/Imu", ("/imu_driver",), ("/estimator",)),
        "/pose": TopicInfo("/pose", "geometry_msgs/Pose", ("/estimator",), ("/blackbox",)),
    }
    observers = [FakeObserver("hz", Resource(topic="/imu")),
                 FakeObserver("timeout", Resource(topic="/imu")),
                 FakeObserver("scores", Resource(topic="/pose"))]
    engine = DiagnosisEngine.from_graph(GraphSnapshot(0.0, nodes, topics), observers)
    d = engine.update(1.0, [Observation(1.0, "hz", Resource(topic="/imu"), Code.GENERAL_OK),
                            Observation(1.0, "timeout", Resource(topic="/imu"), Code.GENERAL_OK),
                            Observation(1.0, "scores", Resource(topic="/pose"),
                                        Code.NO_STATE_FITS)])
    assert d is not None
    assert [set(c) for c in d.candidates] == [{"/estimator"}, {"/imu_driver"}]
    assert "Nothing observes the values of /imu" in d.explanation


def test_a_search_kept_off_the_cpu_is_not_cut_short_by_its_budget():
    # Each consistency check waits longer than the whole budget without using the CPU, as a
    # diagnosis preempted on a loaded robot does: the budget counts CPU, so the search still
    # completes with the same candidates a quiet machine finds.
    import time

    quiet = diagnose(KILL_USB_CAM | {("hz", "/audio")})
    engine = DiagnosisEngine.from_model_file(THESIS_MODEL, time_budget=0.02)
    check = engine.checker.conflict

    def preempted(*args, **kwargs):
        time.sleep(0.03)
        return check(*args, **kwargs)

    engine.checker.conflict = preempted  # type: ignore[method-assign]
    d = engine.update(1.0, observations(engine, KILL_USB_CAM | {("hz", "/audio")}))
    assert d is not None and d.complete
    assert [set(c) for c in d.candidates] == quiet


def _engine(nodes, specs, **kw) -> DiagnosisEngine:
    from blackbox.diagnose.robot_model import NodeSpec, build_model

    return DiagnosisEngine(build_model([NodeSpec(*n) for n in nodes], specs), **kw)


def test_two_faulty_producers_rank_before_one_node_upstream_of_both():
    # /a feeds /b and /c; the values of /y and /z are wrong and nothing judges /x. /a alone
    # explains both only if its wrong values cross /b and /c (two unlikely steps): the
    # producers of the two wrong topics rank first (issue 22: /teleop alone outranked the
    # two faulty sensors by cardinality).
    specs = [ObservationSpec("liveness", Resource(topic="/y")),
             ObservationSpec("liveness", Resource(topic="/z"))]
    engine = _engine([("/a", ("/x",)), ("/b", ("/y",), ("/x",)), ("/c", ("/z",), ("/x",))],
                     specs)
    d = engine.update(1.0, [Observation(1.0, s.type, s.resource, Code.NO_STATE_FITS)
                            for s in specs])
    assert d is not None
    assert [set(c) for c in d.candidates] == [{"/b", "/c"}, {"/a"}]
    assert engine.value_hops(d.candidates, [s.key() for s in specs]) == {
        frozenset({"/b", "/c"}): 0, frozenset({"/a"}): 2}


def test_a_new_failure_two_candidates_explain_alike_keeps_the_blame_where_it_was():
    # /p and /q are each the only suspect of their own liveness and tie on the relation of
    # their topics. The node blamed before stays first when the relation fails after it.
    liveness_q = ObservationSpec("liveness", Resource(topic="/y"))
    relation = ObservationSpec("relation", Resource(topic="/x", topic_b="/y"))
    nodes = [("/p", ("/x",)), ("/q", ("/y",))]

    def code(failed: bool) -> Code:
        return Code.NO_STATE_FITS if failed else Code.GENERAL_OK

    fresh = _engine(nodes, [liveness_q, relation])
    d = fresh.update(1.0, [Observation(1.0, "relation", relation.resource, code(True)),
                           Observation(1.0, "liveness", liveness_q.resource, code(False))])
    assert d is not None and [set(c) for c in d.candidates] == [{"/p"}, {"/q"}]  # by name

    engine = _engine(nodes, [liveness_q, relation])
    engine.update(1.0, [Observation(1.0, "liveness", liveness_q.resource, code(True)),
                        Observation(1.0, "relation", relation.resource, code(False))])
    assert engine.blamed == {"/q"}
    d = engine.update(2.0, [Observation(2.0, "relation", relation.resource, code(True)),
                            Observation(2.0, "liveness", liveness_q.resource, code(False))])
    assert d is not None and [set(c) for c in d.candidates] == [{"/q"}, {"/p"}]
    rebuilt = _engine(nodes, [liveness_q, relation], blamed=engine.blamed)
    d = rebuilt.update(2.0, [Observation(2.0, "relation", relation.resource, code(True)),
                             Observation(2.0, "liveness", liveness_q.resource, code(False))])
    assert d is not None and [set(c) for c in d.candidates] == [{"/q"}, {"/p"}]


def test_a_driver_whose_wrong_values_reach_the_odometry_ranks_as_the_driver_and_odometry():
    # The real robots' three overlapping faults in miniature: the wheel driver's values are
    # noisy (liveness) and the odometry disagrees with the command, the wheels and the
    # current. {driver} alone explains it all by its wrong values crossing the odometry node
    # (two crossings); {odometry, teleop} needs one. A faulty odometry node beside the driver is
    # likelier than the crossings, so the driver ranks as that pair, before the pair that
    # needs a crossing (before: /teleop reported, a false alarm on both middlewares).
    from blackbox.observe.base import JudgedSignals

    liveness = ObservationSpec("liveness", Resource(topic="/joint_states"))
    cmd_odom = ObservationSpec("relation", Resource(topic="/cmd_vel", topic_b="/odom"))
    wheels_odom = ObservationSpec("relation", Resource(topic="/joint_states", topic_b="/odom"))
    current_odom = ObservationSpec("relation", Resource(topic="/battery", topic_b="/odom"))
    specs = [liveness, cmd_odom, wheels_odom, current_odom]
    signals = {cmd_odom.key(): JudgedSignals((("/cmd_vel", "v"), ("/odom", "v")),
                                             (("/cmd_vel", "v"), ("/odom", "v"))),
               current_odom.key(): JudgedSignals((("/battery", "current"), ("/odom", "v")),
                                                 (("/battery", "current"), ("/odom", "v"))),
               wheels_odom.key(): JudgedSignals((("/joint_states", "v"), ("/odom", "v")),
                                                (("/joint_states", "v"), ("/odom", "v")))}
    engine = _engine([("/teleop", ("/cmd_vel",)),
                      ("/base_driver", ("/joint_states",), ("/cmd_vel",)),
                      ("/odometry", ("/odom",), ("/joint_states",)),
                      ("/battery_monitor", ("/battery",))], specs, signals=signals)
    d = engine.update(1.0, [Observation(1.0, s.type, s.resource, Code.NO_STATE_FITS)
                            for s in specs])
    assert d is not None
    assert [set(c) for c in d.candidates] == [{"/base_driver"}, {"/odometry", "/teleop"}]


def test_with_no_explanation_the_operator_reads_which_observations_contradict_each_other():
    # Three sensors of one quantity: /a ~ /b fails while /a ~ /c and /b ~ /c hold, which
    # clear all three signals. No set of faults explains it; the explanation names the
    # failed relation and the two that clear every suspect, not only "check the model".
    from blackbox.observe.base import JudgedSignals

    pairs = [("/a", "/b"), ("/a", "/c"), ("/b", "/c")]
    specs = [ObservationSpec("relation", Resource(topic=x, topic_b=y)) for x, y in pairs]
    signals = {s.key(): JudgedSignals(((x, "v"), (y, "v")), ((x, "v"), (y, "v")))
               for s, (x, y) in zip(specs, pairs, strict=True)}
    engine = _engine([("/pa", ("/a",)), ("/pb", ("/b",)), ("/pc", ("/c",))], specs,
                     signals=signals)
    d = engine.update(1.0, [Observation(1.0, "relation", s.resource,
                                        Code.NO_STATE_FITS if i == 0 else Code.GENERAL_OK)
                            for i, s in enumerate(specs)])
    assert d is not None and d.candidates == () and d.complete
    assert ("No set of modelled components explains them: the failed relation on /a -> /b "
            "contradicts the passing relation on /a -> /c and relation on /b -> /c, which "
            "clear every component that could explain it") in d.explanation
    failed, passing = engine.contradiction() or ((), ())
    assert [o.resource.topic_b for o in failed] == ["/b"]
    assert [o.resource.topic_b for o in passing] == ["/c", "/c"]

    d = engine.update(2.0, [Observation(2.0, "relation", specs[2].resource,
                                        Code.NO_STATE_FITS)])
    assert d is not None and d.candidates == ({"/pb"},)
    assert engine.contradiction() is None


def test_a_relation_failing_with_its_signals_noise_burst_names_the_noisy_sensor():
    # The real ROS 1 robot at 681 s: the IMU's yaw rate had a noise burst. Its liveness
    # check failed and so did command ~ IMU, while IMU ~ odometry and command ~ odometry
    # held and cleared both signals (a zero-mean burst moves no block mean). Held relations
    # see offsets, not bursts: the failed relation is put down to the burst, and the IMU
    # driver explains both (before: no diagnosis at all).
    from blackbox.observe.base import JudgedSignals

    pairs = [("/cmd_vel", "/imu"), ("/imu", "/odom"), ("/cmd_vel", "/odom")]
    relations = [ObservationSpec("relation", Resource(topic=a, topic_b=b)) for a, b in pairs]
    liveness = ObservationSpec("liveness", Resource(topic="/imu"))
    signals = {s.key(): JudgedSignals(((a, "z"), (b, "z")), ((a, "z"), (b, "z")))
               for s, (a, b) in zip(relations, pairs, strict=True)}
    nodes = [("/teleop", ("/cmd_vel",)), ("/imu_driver", ("/imu",)),
             ("/base_driver", ("/wheels",), ("/cmd_vel",)),
             ("/odometry", ("/odom",), ("/wheels",))]
    engine = _engine(nodes, [*relations, liveness], signals=signals)

    def seen(failed: set[ObservationSpec]) -> list[Observation]:
        return [Observation(1.0, s.type, s.resource,
                            Code.NO_STATE_FITS if s in failed else Code.GENERAL_OK)
                for s in (*relations, liveness)]

    d = engine.update(1.0, seen({relations[0], liveness}))
    assert d is not None and [set(c) for c in d.candidates] == [{"/imu_driver"}]
    d = engine.update(2.0, seen({relations[0]}))  # the same failure without the burst
    assert d is not None and d.candidates == () and d.complete
    assert ("the failed relation on /cmd_vel -> /imu contradicts the passing relation on "
            "/cmd_vel -> /odom and relation on /imu -> /odom, which clear") in d.explanation
