"""`blackbox learn` on the simulated robot: what a learned configuration contains, that it
stays quiet on a healthy robot and sees injected faults, and the rules it is made by."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
import yaml

from blackbox.cli import main
from blackbox.learn import Learned, learn_from, render_config, render_model
from blackbox.learn.fields import classify, discover
from blackbox.learn.model import cpu_limit
from blackbox.learn.stats import SHIFT_SIGMAS, learn_bounds, round_down, round_up
from blackbox.model import Observation, Resource
from blackbox.observe.build import build_observers, load_config
from blackbox.pipeline import Pipeline
from blackbox.sinks import SinkBase
from blackbox.sources.sim import Fault, open_sim


class Collect(SinkBase):
    def __init__(self) -> None:
        self.observations: list[Observation] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self.observations.extend(observations)


SHARES_THE_LEARNED_THESIS = pytest.mark.xdist_group("test_learn_thesis")
"""On one worker: the learned configuration is made once per process (half a minute of
CPU); spread over three workers it was made three times."""


@functools.cache
def learned_thesis() -> tuple[Learned, str]:
    learned = learn_from(lambda: open_sim("sim:thesis", seed=42, realtime=False), 180.0)
    return learned, render_config(learned, "thesis-robot", "robot.model.yaml", "now")


def write_learned(tmp_path: Path) -> Path:
    learned, text = learned_thesis()
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    (tmp_path / "robot.model.yaml").write_text(render_model(learned, "now"))
    return path


def run(config: Path, duration: float, faults: Sequence[Fault] = (), seed: int = 3
        ) -> list[Observation]:
    sink = Collect()
    source = open_sim("sim:thesis", faults=list(faults), seed=seed, realtime=False)
    Pipeline(source, build_observers(load_config(config)), [sink]).run(duration=duration)
    return sink.observations


@SHARES_THE_LEARNED_THESIS
def test_learned_thesis_configuration_observes_every_node_and_topic(tmp_path: Path) -> None:
    config = load_config(write_learned(tmp_path))
    entries = [e.to_python() for e in config.observers]
    kinds = {(e["type"], e.get("topic") or e.get("node")) for e in entries}
    for node in ("/usb_cam", "/audio_capture", "/Signal_generator"):
        assert ("activated", node) in kinds and ("resources", node) in kinds
    for topic in ("/usb_cam/image_raw", "/audio", "/signal"):
        assert ("hz", topic) in kinds and ("timeout", topic) in kinds
    assert ("timestamp", "/usb_cam/image_raw") in kinds  # the only stamped message
    assert ("fields", "/signal") in kinds
    signal = next(e for e in entries if e["type"] == "fields")
    bounds = signal["states"][0]["data"]["value"]
    assert 14.0 < bounds["lower_bound"] < 14.6 and 15.4 < bounds["upper_bound"] < 16.0
    hz = next(e for e in entries if e["type"] == "hz" and e["topic"] == "/signal")
    period = hz["states"][0]["period"]["value"]
    assert period["lower_bound"] < 1 / 15 < period["upper_bound"]
    # the band is the learned one widened to RATE_TOLERANCE (40 %) of the period each side
    assert 0.55 / 15 < period["lower_bound"] < 0.62 / 15
    assert 1.38 / 15 < period["upper_bound"] < 1.45 / 15
    assert len(build_observers(config)) == len(entries)


@SHARES_THE_LEARNED_THESIS
def test_constants_counters_and_stamps_are_named_not_observed(tmp_path: Path) -> None:
    raw = write_learned(tmp_path).read_text()
    text = " ".join(line.strip().lstrip("#").strip() for line in raw.splitlines())
    assert "header.seq counter: counts by 1 per message" in text
    assert "height constant: always 480" in text
    assert "mean(data) constant" in text   # the simulator's camera sends one frame
    fields = [e.to_python() for e in load_config(tmp_path / "robot.yaml").observers
              if e["type"].str() == "fields"]
    assert [f["topic"] for f in fields] == ["/signal"]


@SHARES_THE_LEARNED_THESIS
def test_learned_model_is_the_graph(tmp_path: Path) -> None:
    write_learned(tmp_path)
    model = yaml.safe_load((tmp_path / "robot.model.yaml").read_text())
    nodes = {n["name"]: n for n in model["nodes"]}
    assert nodes["/Signal_generator"]["sub_topic"] == ["/audio", "/usb_cam/image_raw"]
    assert nodes["/usb_cam"]["pub_topic"] == ["/usb_cam/image_raw"]
    from blackbox.diagnose.robot_model import load_robot_model

    assert len(load_robot_model(tmp_path / "robot.model.yaml").nodes) == 3


@SHARES_THE_LEARNED_THESIS
def test_learned_configuration_is_quiet_on_another_healthy_run(tmp_path: Path) -> None:
    observations = run(write_learned(tmp_path), 600.0, seed=9)
    assert len({o.key() for o in observations}) == 15  # + liveness of /signal
    assert [o for o in observations if o.faulty] == []


@pytest.mark.parametrize("topic", ["/usb_cam/image_raw", "/audio", "/signal"])
@SHARES_THE_LEARNED_THESIS
def test_a_pause_of_the_robot_computer_under_a_second_is_no_rate_fault(
        tmp_path: Path, topic: str) -> None:
    """A loaded robot computer stops a publisher for 0.7 s now and then; a learned rate
    band is judged over two seconds of messages, so such a pause stays inside it."""
    observations = run(write_learned(tmp_path), 80.0, [Fault("stall", topic, 60, 60.7)])
    assert [o for o in observations if o.faulty] == []


@pytest.mark.parametrize(("fault", "observer", "resource", "within"), [
    (Fault("kill", "/usb_cam", 60, 70), "activated", Resource(node="/usb_cam"), 2.0),
    (Fault("stall", "/audio", 60, 70), "timeout", Resource(topic="/audio"), 2.0),
    # a rate band is judged over two seconds of messages (a loaded computer's pause of
    # 0.8 s stays inside it): a publisher at 60 % of its rate leaves it within three
    (Fault("rate", "/signal", 60, 70, {"factor": 0.6}), "hz", Resource(topic="/signal"), 3.0),
    (Fault("offset", "/signal", 60, 70, {"value": 2.0}), "fields", Resource(topic="/signal"),
     2.0),
    (Fault("stuck", "/signal", 60, 70), "fields", Resource(topic="/signal"), 2.0),
    (Fault("cpu_hog", "/audio_capture", 60, 70, {"percent": 60.0}), "resources",
     Resource(node="/audio_capture"), 2.0),
], ids=["kill", "stall", "rate", "offset", "stuck", "cpu_hog"])
@SHARES_THE_LEARNED_THESIS
def test_learned_configuration_sees_injected_faults_within_seconds(
        tmp_path: Path, fault: Fault, observer: str, resource: Resource, within: float) -> None:
    observations = run(write_learned(tmp_path), 80.0, [fault])
    hits = [o for o in observations if o.faulty and o.observer == observer
            and o.resource == resource]
    assert hits and 60.0 <= hits[0].time <= 60.0 + within, hits[:1]
    before = [o for o in observations if o.faulty and o.time < 60.0]
    assert before == []


@SHARES_THE_LEARNED_THESIS
def test_a_node_whose_cpu_share_more_than_doubles_on_a_loaded_host_is_no_fault(
        tmp_path: Path) -> None:
    """``/Signal_generator`` runs at about 6 % of a core; a loaded host can read it at well
    over twice that (cold caches, context switches) without any fault of the node."""
    observations = run(write_learned(tmp_path), 80.0,
                       [Fault("cpu_hog", "/Signal_generator", 60, 70, {"percent": 14.0})])
    assert [o for o in observations if o.faulty] == []


def test_the_cpu_bound_leaves_a_node_its_own_high_mark_again_and_at_least_ten_points() -> None:
    assert cpu_limit(5.0, 6.5) == 16.5
    assert cpu_limit(30.0, 40.0) == 80.0
    assert cpu_limit(0.0, 45.0) < 95.0  # a busy thread, a whole core, is still seen


# ---- the rules --------------------------------------------------------------------------------

def test_window_rule_takes_the_smallest_window_that_catches_a_two_sigma_shift() -> None:
    rng = np.random.default_rng(1)
    x = 10.0 + rng.normal(0.0, 1.0, 20_000)
    b = learn_bounds(x)
    assert b is not None and b.sensitive and b.window > 1
    assert b.upper - b.center <= SHIFT_SIGMAS * b.sigma
    assert b.lower < 10.0 < b.upper
    smaller = learn_bounds(x, max_window=b.window - 1)
    assert smaller is not None and not smaller.sensitive  # why the window is not smaller


def test_window_rule_on_constant_and_short_series() -> None:
    constant = learn_bounds([0.0] * 100, floor=0.05)
    assert constant is not None and constant.window == 1
    assert (constant.lower, constant.upper) == (-0.05, 0.05)
    assert learn_bounds([1.0, 2.0, 3.0]) is None


def test_rounding_never_narrows_bounds() -> None:
    assert round_down(0.0633349) == 0.06333 and round_up(0.0633301) == 0.06334
    assert round_down(-14.27001) == -14.28 and round_up(49_012_345.0) == 49_020_000.0


@pytest.mark.parametrize(("series", "integer", "kind"), [
    ([5.0] * 30, False, "constant"),
    (list(range(1, 31)), True, "counter"),
    ([0.5 * i + 0.01 * (i % 3) for i in range(30)], False, "monotonic"),
    ([0, 1, 2, 1, 0, 2] * 5, True, "discrete"),
    ([15.0 + ((7 * i) % 11 - 5) / 10 for i in range(30)], False, "numeric"),
])
def test_series_classes(series: list[float], integer: bool, kind: str) -> None:
    assert classify(np.asarray(series, dtype=float), integer).kind == kind


def test_fields_are_found_by_walking_the_message() -> None:
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    Scan = store.types["sensor_msgs/msg/LaserScan"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    scan = Scan(Header(1, Time(5, 0), "laser"), -1.0, 1.0, 0.1, 0.0, 0.1, 0.1, 30.0,
                np.ones(20, dtype=np.float32), np.zeros(0, dtype=np.float32))
    found = {f.path: f.kind for f in discover(scan).fields}
    assert found["header.stamp"] == "stamp"
    assert found["header.seq"] == "scalar" and found["angle_min"] == "scalar"
    assert found["ranges"] == "array" and "intensities" not in found
    assert "intensities (empty array)" in discover(scan).skipped
    assert "header.frame_id" not in found


def test_cli_learns_and_check_config_accepts_the_file(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli.yaml"
    assert main(["learn", "--source", "sim:thesis", "--simulated-clock", "--duration", "60",
                 "--seed", "3", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "learning [" in err and "100.0 %" in err
    assert out.is_file() and (tmp_path / "cli.model.yaml").is_file()
    assert main(["check-config", str(out)]) == 0
    assert main(["learn", "--source", "bogus:x", "-o", str(tmp_path / "x.yaml")]) == 2
    assert "unknown source" in capsys.readouterr().err


def test_a_topic_with_two_publishers_gets_one_rate_observer_per_publisher() -> None:
    from blackbox.events import GraphSnapshot, MessageArrival, NodeInfo, TopicInfo
    from blackbox.observe.build import load_config_text
    from blackbox.sources.memory import MemorySource

    nodes = {n: NodeInfo(n, True) for n in ("/left", "/right")}
    graph = GraphSnapshot(0.0, nodes, {"/wheel": TopicInfo("/wheel", "std_msgs/Float64",
                                                           ("/left", "/right"), ())})
    events: list = [graph]
    events += [MessageArrival(0.1 * i, "/wheel", "/left", 8) for i in range(1, 300)]
    events += [MessageArrival(0.25 * i + 0.01, "/wheel", "/right", 8) for i in range(1, 120)]
    learned = learn_from(lambda: MemorySource(events), 30.0)
    config = load_config_text(render_config(learned, "r", "m.yaml", "now"), "r.yaml")
    hz = {tuple(e["publishers"].str_list()): e.to_python() for e in config.observers
          if e["type"].str() == "hz"}
    assert set(hz) == {("/left",), ("/right",)}
    left = hz[("/left",)]["states"][0]["period"]["value"]
    right = hz[("/right",)]["states"][0]["period"]["value"]
    assert left["lower_bound"] < 0.1 < left["upper_bound"] < 0.25
    assert right["lower_bound"] < 0.25 < right["upper_bound"]


@SHARES_THE_LEARNED_THESIS
def test_learned_configuration_scores_at_least_the_hand_written_one(tmp_path: Path) -> None:
    """A short version of benchmarks/learn_evaluation.py (docs/evaluation.md)."""
    from blackbox.app import DEFAULT_CONFIG
    from blackbox.evaluate import CampaignSettings, run_campaign

    learned = write_learned(tmp_path)
    results = {name: run_campaign(CampaignSettings(config=config, runs=2, duration=120.0))
               for name, config in (("hand", DEFAULT_CONFIG), ("learned", learned))}
    hand, mine = results["hand"], results["learned"]
    assert mine.confusion.fp == 0
    assert (mine.confusion.f1 or 0.0) >= (hand.confusion.f1 or 0.0)
    assert mine.diagnosis is not None and hand.diagnosis is not None
    assert mine.diagnosis.in_candidates >= hand.diagnosis.in_candidates
    # Top-1 on two short runs hangs on one tie (a concurrent upstream fault whose values
    # nothing judges explains the symptom alone); the full campaign compares it.
    assert mine.diagnosis.isolated >= hand.diagnosis.isolated - 1
