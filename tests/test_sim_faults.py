"""Fault injection: each kind changes exactly what it should, on exactly its component.

Every fault run is compared with the fault-free run of the same seed: everything outside
the faulty component must be identical, event for event.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import GraphSnapshot, Interest, MessageArrival, ResourceSample
from blackbox.sources.sim import (
    FAULT_KINDS,
    THESIS_FAULT_KINDS,
    Fault,
    GroundTruth,
    SimulatedSource,
    Topology,
    load_faults,
    open_sim,
    random_campaign,
    read_ground_truth,
    write_ground_truth,
)
from blackbox.sources.sim.topology import THESIS_FILE

THESIS = Topology.thesis()
EVERYTHING = Interest(topics=frozenset(THESIS.topics), decoded=frozenset({"/signal"}),
                      resources=frozenset(THESIS.nodes), network=False)
SEED = 11


def run(faults: list[Fault], seconds: float = 40.0, topology: Topology = THESIS,
        seed: int = SEED) -> tuple[SimulatedSource, list]:
    source = SimulatedSource(topology, faults, seed=seed)
    interest = EVERYTHING if topology is THESIS else Interest(
        topics=frozenset(topology.topics), resources=frozenset(topology.nodes))
    source.start(interest)
    events = []
    for k in range(1, int(seconds) + 1):
        events += source.poll(float(k))
    return source, events


BASELINE = run([])[1]


def times(events: list, topic: str, lo: float = 0.0, hi: float = 1e9) -> list[float]:
    return [e.time for e in events
            if isinstance(e, MessageArrival) and e.topic == topic and lo <= e.time < hi]


def values(events: list, lo: float = 0.0, hi: float = 1e9) -> list[tuple[float, float]]:
    return [(e.time, e.value.data) for e in events
            if isinstance(e, MessageArrival) and e.topic == "/signal" and lo <= e.time < hi]


def resources(events: list, node: str) -> dict[float, ResourceSample]:
    return {e.time: e for e in events if isinstance(e, ResourceSample) and e.node == node}


def signature(events: list, exclude_topic: str = "", exclude_node: str = "") -> list:
    """What a run looks like outside one component."""
    out = []
    for e in events:
        if isinstance(e, MessageArrival) and e.topic != exclude_topic:
            out.append((e.time, e.topic, e.value.data if e.topic == "/signal" else e.size))
        elif isinstance(e, ResourceSample) and e.node != exclude_node:
            out.append((e.time, e.node, e.cpu_percent, e.memory_bytes))
    return out


# ---- kill ----

def test_kill_takes_the_node_out_of_the_graph_at_once_and_silences_its_topics():
    _source, events = run([Fault("kill", "/usb_cam", 10.25, 20.5)])
    changes = [e for e in events if isinstance(e, GraphSnapshot) and e.time == 10.25]
    assert len(changes) == 1
    cam = changes[0].nodes["/usb_cam"]
    assert (cam.alive, cam.pid) == (False, None)
    assert changes[0].nodes["/audio_capture"].alive
    assert times(events, "/usb_cam/image_raw", 10.25, 20.5) == []
    assert times(events, "/usb_cam/image_raw", 10.0, 10.25) != []
    # restarted with a new pid, publishing again within one period
    restart = next(e for e in events if isinstance(e, GraphSnapshot) and e.time == 20.5)
    assert restart.nodes["/usb_cam"].alive
    assert restart.nodes["/usb_cam"].pid not in (None, 2101)
    first = times(events, "/usb_cam/image_raw", 20.5)[0]
    assert first < 20.5 + 1 / 15
    samples = resources(events, "/usb_cam")
    dead = [samples[float(t)] for t in range(11, 21)]
    assert all(s.cpu_percent is None and s.memory_bytes is None and s.reason for s in dead)
    assert samples[21.0].cpu_percent is not None
    # the rest of the robot, the signal generator included, is untouched
    assert signature(events, "/usb_cam/image_raw", "/usb_cam") == signature(
        BASELINE, "/usb_cam/image_raw", "/usb_cam")


def test_a_node_requiring_a_killed_input_stops_after_its_timeout():
    text = THESIS_FILE.read_text()
    text = text.replace("    # requires: {topics: [/usb_cam/image_raw, /audio], timeout: 1.0}",
                        "    requires: {topics: [/usb_cam/image_raw, /audio], timeout: 1.0}")
    robot = Topology.parse(text)
    assert robot.nodes["/Signal_generator"].requires == ("/usb_cam/image_raw", "/audio")
    _, events = run([Fault("kill", "/usb_cam", 10.0, 20.0)], topology=robot)
    last_image = times(events, "/usb_cam/image_raw", 0, 10.0)[-1]
    silent = times(events, "/signal", last_image + 1.0 + 1 / 15, 20.0)
    assert silent == []
    assert times(events, "/signal", 10.0, last_image + 1.0) != []  # still within the timeout
    assert times(events, "/signal", 20.0, 21.0) != []  # back once images are
    assert times(events, "/audio", 10.0, 20.0) != []


# ---- topic faults ----

def test_stall_stops_one_topic_while_the_node_lives():
    _, events = run([Fault("stall", "/audio", 10.0, 20.0)])
    assert times(events, "/audio", 10.0, 20.0) == []
    assert len(times(events, "/audio", 20.0, 30.0)) == pytest.approx(333, abs=2)
    graphs = [e for e in events if isinstance(e, GraphSnapshot) and 10 <= e.time < 20]
    assert all(g.nodes["/audio_capture"].alive for g in graphs)
    assert all(s.cpu_percent is not None for s in resources(events, "/audio_capture").values())
    assert signature(events, "/audio") == signature(BASELINE, "/audio")


def test_rate_factor_half_halves_the_count():
    _, events = run([Fault("rate", "/signal", 10.0, 30.0, {"factor": 0.5})])
    assert len(times(events, "/signal", 10.0, 30.0)) == pytest.approx(150, abs=2)
    assert len(times(events, "/signal", 30.0, 40.0)) == pytest.approx(150, abs=2)
    assert len(times(BASELINE, "/signal", 10.0, 30.0)) == pytest.approx(300, abs=2)
    assert signature(events, "/signal") == signature(BASELINE, "/signal")


def test_rate_can_be_set_in_hz():
    _, events = run([Fault("rate", "/usb_cam/image_raw", 10.0, 30.0, {"hz": 12.0})])
    assert len(times(events, "/usb_cam/image_raw", 10.0, 30.0)) == pytest.approx(240, abs=2)


# ---- value faults ----

def test_offset_shifts_values_only_while_active():
    _, events = run([Fault("offset", "/signal", 10.0, 20.0, {"value": 3.0})])
    assert all(17.5 <= v <= 18.5 for _, v in values(events, 10.0, 20.0))
    assert all(14.5 <= v <= 15.5 for _, v in values(events, 20.0))
    base = dict(values(BASELINE))
    assert all(v == pytest.approx(base[t] + 3.0) for t, v in values(events, 10.0, 20.0))
    assert times(events, "/signal") == times(BASELINE, "/signal")


def test_scale_multiplies_values():
    _, events = run([Fault("scale", "/signal", 10.0, 20.0, {"factor": 2.0})])
    assert all(29.0 <= v <= 31.0 for _, v in values(events, 10.0, 20.0))
    assert all(14.5 <= v <= 15.5 for _, v in values(events, 0.0, 10.0))


def test_stuck_freezes_the_last_value():
    _, events = run([Fault("stuck", "/signal", 10.0, 20.0)])
    last_before = values(events, 0.0, 10.0)[-1][1]
    during = {v for _, v in values(events, 10.0, 20.0)}
    assert during == {last_before}
    assert len({v for _, v in values(events, 20.0)}) > 100


def test_drift_grows_with_time():
    _, events = run([Fault("drift", "/signal", 10.0, 30.0, {"rate": 0.1})])
    base = dict(values(BASELINE))
    for t, v in values(events, 10.0, 30.0):
        assert v == pytest.approx(base[t] + 0.1 * (t - 10.0))
    assert min(v for _, v in values(events, 25.0, 30.0)) > 15.5  # out of band after 10 s



def test_noise_adds_gaussian_noise_of_sigma_and_leaves_the_mean():
    _, events = run([Fault("noise", "/signal", 10.0, 30.0, {"sigma": 0.4})], seconds=45.0)
    base = dict(values(run([], seconds=45.0)[1]))
    added = [v - base[t] for t, v in values(events, 10.0, 30.0)]
    assert len(added) == pytest.approx(300, abs=3)
    mean = sum(added) / len(added)
    std = (sum((a - mean) ** 2 for a in added) / len(added)) ** 0.5
    assert abs(mean) < 0.1 and std == pytest.approx(0.4, rel=0.2)
    # before and after the fault the values are the fault-free run's, sample for sample
    assert values(events, 0.0, 10.0) == values(BASELINE, 0.0, 10.0)
    assert values(events, 30.0) == [(t, base[t]) for t, _ in values(events, 30.0)]


def test_noise_is_deterministic_per_seed():
    fault = [Fault("noise", "/signal", 5.0, 15.0, {"sigma": 0.3})]
    assert values(run(fault, seconds=20.0)[1]) == values(run(fault, seconds=20.0)[1])
    assert values(run(fault, seconds=20.0)[1]) != values(run(fault, seconds=20.0, seed=12)[1])


def test_random_noise_stays_inside_the_normal_range_of_a_moving_signal():
    from blackbox.sources.sim.faults import healthy_spread, noise_std
    from blackbox.sources.sim.messages import scalars_of
    from blackbox.sources.sim.robot import BUILTIN_ROBOTS

    robot = Topology.load(BUILTIN_ROBOTS["diffdrive"])
    faults = [f for seed in range(5)
              for f in random_campaign(robot, 900.0, seed=seed, kinds=["noise"])]
    assert len(faults) > 100
    for f in faults:
        scalars = scalars_of(robot.topics[f.component].value)
        model = next(s for s in scalars if f.field in (None, s.field))
        sigma = f.params["sigma"]
        assert sigma >= 3.0 * noise_std(model) - 1e-4          # a fault, not more of the same
        assert sigma <= 0.5 * healthy_spread(model, robot) + 1e-4 or (
            sigma <= 6.0 * noise_std(model) + 1e-4)            # inside the signal's range


# ---- node resources ----

def test_cpu_hog_raises_cpu_of_that_node_only():
    _, events = run([Fault("cpu_hog", "/audio_capture", 10.0, 20.0, {"percent": 95.0})])
    samples = resources(events, "/audio_capture")
    assert all(94.4 <= samples[float(t)].cpu_percent <= 95.6 for t in range(10, 20))
    assert all(samples[float(t)].cpu_percent < 5.0 for t in range(20, 41))
    assert signature(events, exclude_node="/audio_capture") == signature(
        BASELINE, exclude_node="/audio_capture")


def test_memory_growth_grows_memory_and_end_frees_it():
    _, events = run([Fault("memory_growth", "/Signal_generator", 10.0, 20.0,
                           {"rate": 1_000_000.0})])
    samples = resources(events, "/Signal_generator")
    base = resources(BASELINE, "/Signal_generator")
    for t in range(10, 20):
        grown = samples[float(t)].memory_bytes - base[float(t)].memory_bytes
        assert grown == pytest.approx(1_000_000.0 * (t - 10))
    assert samples[25.0].memory_bytes == base[25.0].memory_bytes


# ---- ground truth ----

def test_ground_truth_records_every_injected_fault(tmp_path: Path):
    faults = [Fault("kill", "/usb_cam", 5.0, 8.0), Fault("offset", "/signal", 12.0, None,
                                                         {"value": 2.0}),
              Fault("stall", "/audio", 100.0, 110.0)]
    source = SimulatedSource(THESIS, faults, start_time=1000.0)
    source.start(EVERYTHING)
    source.poll(1006.0)
    assert source.ground_truth == [GroundTruth(1005.0, None, "kill", "/usb_cam", "/usb_cam")]
    source.poll(1040.0)
    truth = source.ground_truth
    assert truth == [GroundTruth(1005.0, 1008.0, "kill", "/usb_cam", "/usb_cam"),
                     GroundTruth(1012.0, None, "offset", "/signal", "/Signal_generator",
                                 {"value": 2.0})]
    assert truth[1].to_dict() == {"start": 1012.0, "end": None, "kind": "offset",
                                  "component": "/signal", "node": "/Signal_generator",
                                  "params": {"value": 2.0}}
    path = tmp_path / "truth.jsonl"
    write_ground_truth(truth, path)
    assert len(path.read_text().splitlines()) == 2
    assert read_ground_truth(path) == truth


# ---- validation ----

@pytest.mark.parametrize(("fault", "message"), [
    (lambda: Fault("explode", "/usb_cam", 1.0), "unknown fault kind"),
    (lambda: Fault("rate", "/signal", 1.0), "exactly one of factor, hz"),
    (lambda: Fault("rate", "/signal", 1.0, params={"factor": 0.5, "hz": 3}), "exactly one"),
    (lambda: Fault("rate", "/signal", 1.0, params={"factor": -1}), "positive"),
    (lambda: Fault("offset", "/signal", 1.0, params={"factor": 1}), "unknown parameter"),
    (lambda: Fault("kill", "/usb_cam", 5.0, 5.0), "end must be after start"),
    (lambda: Fault("kill", "/usb_cam", -1.0), "start must be"),
])
def test_invalid_faults(fault, message):
    with pytest.raises(ValueError, match=message):
        fault()


def test_faults_must_fit_the_robot():
    with pytest.raises(ValueError, match="no node /ghost"):
        SimulatedSource(THESIS, [Fault("kill", "/ghost", 1.0)])
    with pytest.raises(ValueError, match="no numeric value model"):
        SimulatedSource(THESIS, [Fault("offset", "/usb_cam/image_raw", 1.0,
                                       params={"value": 1.0})])


# ---- random campaigns ----

def test_random_campaign_is_reproducible_and_never_overlaps_on_a_node():
    a = random_campaign(THESIS, 300.0, seed=5)
    assert a == random_campaign(THESIS, 300.0, seed=5)
    assert a != random_campaign(THESIS, 300.0, seed=6)
    assert len(a) >= 5
    owner = {t.name: t.publisher for t in THESIS.topics.values()}
    per_node: dict[str, list[Fault]] = {}
    for f in a:
        assert 5.0 <= f.start < 300.0
        assert 5.0 <= f.end - f.start <= 15.0 + 1e-3
        f.check(THESIS)
        per_node.setdefault(owner.get(f.component, f.component), []).append(f)
    for faults in per_node.values():
        faults.sort(key=lambda f: f.start)
        for earlier, later in itertools.pairwise(faults):
            assert earlier.end <= later.start


def test_random_campaign_honours_kinds_and_fixed_parameters():
    faults = random_campaign(THESIS, 200.0, seed=1, kinds={"rate": {"factor": 0.5},
                                                           "kill": {}},
                             mean_gap=5.0, duration_range=(2.0, 4.0), min_separation=3.0)
    assert {f.kind for f in faults} == {"rate", "kill"}
    assert all(dict(f.params) == {"factor": 0.5} for f in faults if f.kind == "rate")
    thesis = random_campaign(THESIS, 300.0, seed=1, kinds=THESIS_FAULT_KINDS)
    assert {f.kind for f in thesis} <= {"kill", "stall", "rate", "offset", "scale"}
    values_only = random_campaign(THESIS, 200.0, seed=1, kinds=["offset", "drift"])
    assert {f.component for f in values_only} == {"/signal"}
    with pytest.raises(ValueError, match="unknown fault kind"):
        random_campaign(THESIS, 10.0, seed=1, kinds=["melt"])


def test_a_five_minute_random_campaign_runs_and_is_logged():
    faults = random_campaign(THESIS, 300.0, seed=2, kinds=tuple(FAULT_KINDS))
    source, _events = run(faults, seconds=300.0)
    truth = source.ground_truth
    assert [(t.kind, t.component, t.start) for t in truth] == [
        (f.kind, f.component, f.start) for f in faults]
    assert all(t.end == f.end for t, f in zip(truth, faults, strict=True) if f.end <= 300.0)


# ---- YAML ----

FAULTS_YAML = """\
faults:
  - {kind: kill, component: /usb_cam, start: 30, end: 45}
  - kind: rate
    component: /signal
    start: 60
    factor: 0.5
random:
  duration: 300
  seed: 3
  kinds: [stall, offset]
  mean_gap: 20
  duration_range: [5, 10]
"""


def test_faults_from_yaml():
    faults = load_faults(ConfigNode.parse(FAULTS_YAML, "faults.yaml"), THESIS)
    assert Fault("kill", "/usb_cam", 30.0, 45.0) in faults
    assert Fault("rate", "/signal", 60.0, None, {"factor": 0.5}) in faults
    campaign = random_campaign(THESIS, 300.0, seed=3, kinds=("stall", "offset"),
                               mean_gap=20.0, duration_range=(5.0, 10.0))
    assert all(f in faults for f in campaign)
    assert len(faults) == 2 + len(campaign)
    assert [f.start for f in faults] == sorted(f.start for f in faults)


@pytest.mark.parametrize(("change", "line", "path", "message"), [
    (("/usb_cam, start", "/usb_camm, start"), 2, "faults[0].component", "no node /usb_camm"),
    (("factor: 0.5", "value: 0.5"), 6, "faults[1].value", "rate takes no parameter 'value'"),
    (("    factor: 0.5\n", ""), 3, "faults[1]", "exactly one of factor, hz"),
    (("kinds: [stall, offset]", "kinds: [stall, ofset]"), 10, "random.kinds[1]",
     "did you mean 'offset'"),
    (("end: 45", "end: 20"), 2, "faults[0].end", "must be >"),
])
def test_fault_yaml_errors_point_at_the_line(change, line, path, message):
    with pytest.raises(ConfigError) as info:
        load_faults(ConfigNode.parse(FAULTS_YAML.replace(*change), "faults.yaml"), THESIS)
    err = info.value
    assert (err.file, err.line, err.path) == ("faults.yaml", line, path)
    assert message in err.message


def test_open_sim_with_a_fault_file(tmp_path: Path):
    path = tmp_path / "faults.yaml"
    path.write_text(FAULTS_YAML)
    source = open_sim(f"sim:thesis?faults={path}&seed=4")
    assert Fault("kill", "/usb_cam", 30.0, 45.0) in source.faults
    assert source.seed == 4
