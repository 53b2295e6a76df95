"""Learned relations and per-signal liveness, as specifications (issue 22).

Real pieces throughout: the relation and liveness observers fed with messages on a
simulated clock, the calibration on Gaussian data, `blackbox learn` on the simulated
differential-drive robot and the consistency-based engine on its learned model.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.diagnose.robot_model import NodeSpec, ObservationSpec, build_model
from blackbox.events import MessageArrival
from blackbox.learn import learn_from, render_config, render_model
from blackbox.learn.sequential import alarms, calibrate, siegmund_arl, threshold_for
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import JudgedSignals
from blackbox.observe.build import build_observer, load_config
from blackbox.observe.observers.liveness import LivenessObserver, liveness_from_config
from blackbox.observe.observers.relation import RelationObserver, relation_from_config
from blackbox.sources.sim import open_sim

RELATION = """
type: relation
topic: /cmd
topic_b: /imu
step: 0.05
block: 10
window: 2.0
fresh: 0.3
relations:
  - name: imu_z
    target: {topic: /imu, field: z}
    inputs: [{topic: /cmd, field: w, lags: [0.0], gains: [1.0]}]
    intercept: 0.0
    block_noise: 0.01
    cusum: {k: 0.5, h: 10.0}
    excitation: 0.02
    span: [-2.0, 2.0]
"""


def msg(topic: str, t: float, **fields: float) -> MessageArrival:
    return MessageArrival(time=t, topic=topic, publisher="/pub", size=8,
                          value=SimpleNamespace(**fields))


def drive(observer: RelationObserver | LivenessObserver, seconds: float, start: float = 0.0,
          *, offset: float = 0.0, still: bool = False, noise: float = 0.02,
          seed: int = 0) -> list[Observation]:
    """Feed 20 Hz /cmd and /imu that measure one yaw rate; evaluate once a second."""
    rng = np.random.default_rng(seed)
    out: list[Observation] = []
    t = start
    next_eval = math.floor(start) + 1.0
    while t < start + seconds:
        w = 0.0 if still else 0.5 * math.sin(2 * math.pi * t / 7.0)
        observer.on_message(msg("/cmd", t, w=w + rng.normal(0, 0.01)))
        observer.on_message(msg("/imu", t + 0.01, z=w + offset + rng.normal(0, noise)))
        t = round(t + 0.05, 6)
        if t >= next_eval:
            out.extend(observer.evaluate(next_eval))
            next_eval += 1.0
    return out


def relation(text: str = RELATION) -> RelationObserver:
    return relation_from_config(ConfigNode.parse(text))


def test_a_held_relation_says_ok_and_an_offset_inside_the_range_fails_it_within_two_seconds():
    obs = relation()
    healthy = drive(obs, 30.0)
    assert healthy[-1].code == Code.GENERAL_OK, healthy[-1].message
    assert all(o.code != Code.NO_STATE_FITS for o in healthy)
    faulty = drive(obs, 5.0, start=30.0, offset=0.1, seed=1)  # 0.1 << the 0.5 range
    first = next(i for i, o in enumerate(faulty) if o.code == Code.NO_STATE_FITS)
    assert first <= 1, [o.message for o in faulty]
    assert "/imu z disagrees with /cmd w" in faulty[first].message


TRACKED = RELATION.replace("    span: [-2.0, 2.0]\n",
                           "    span: [-2.0, 2.0]\n    track: 2.5\n    track_rate: 0.001\n")


def test_a_followed_bias_starts_where_the_run_starts_not_at_the_learning_runs_mean():
    """A battery discharged on between learning and this run: its relation, which follows
    a slowly moving bias, starts from the first judged block instead of alarming for the
    minute it takes to follow the distance at its bounded rate; a later offset still fails."""
    moved = relation(TRACKED)
    healthy = drive(moved, 30.0, offset=0.03)  # 3 block noise off the learned bias
    assert all(o.code != Code.NO_STATE_FITS for o in healthy), [o.message for o in healthy]
    assert healthy[-1].code == Code.GENERAL_OK, healthy[-1].message
    faulty = drive(moved, 5.0, start=30.0, offset=0.13, seed=1)
    assert any(o.code == Code.NO_STATE_FITS for o in faulty), [o.message for o in faulty]
    untracked = relation()  # without a followed bias the same start is a fault
    assert any(o.code == Code.NO_STATE_FITS for o in drive(untracked, 30.0, offset=0.03))


def test_standing_still_is_unjudged_when_it_was_not_seen_while_learning():
    obs = relation()
    drive(obs, 20.0)
    still = drive(obs, 10.0, start=20.0, still=True, offset=0.1)
    assert still[-1].code == Code.NOT_AVAILABLE
    assert "no excitation" in still[-1].message


def test_a_stale_signal_gives_no_verdict():
    obs = relation()
    drive(obs, 20.0)
    for k in range(40):  # only /cmd for two seconds: /imu stalled
        obs.on_message(msg("/cmd", 20.0 + 0.05 * k, w=0.1))
    last = obs.evaluate(22.0)[0]
    assert last.code == Code.NOT_AVAILABLE and "stale" in last.message


def test_nan_and_inf_are_counted_not_judged():
    obs = relation()
    drive(obs, 20.0)
    for k in range(40):
        t = 20.0 + 0.05 * k
        obs.on_message(msg("/cmd", t, w=0.1))
        obs.on_message(msg("/imu", t, z=math.nan if k % 2 else math.inf))
    last = obs.evaluate(22.0)[0]
    assert last.code == Code.NOT_AVAILABLE


@pytest.mark.parametrize("bad,where", [
    # one topic may relate its own signals, but then the target must be of it
    ("topic_b: /cmd", "relations[0].target.topic"),
    ("relations: []", "relations"),
])
def test_a_malformed_relation_entry_names_its_key(bad: str, where: str):
    key = bad.split(":")[0]
    text = "\n".join(bad if line.startswith(key + ":") else line
                     for line in RELATION.splitlines())
    if key == "relations":
        text = text.split("relations:")[0] + bad
    with pytest.raises(ConfigError) as err:
        relation(text)
    assert where in str(err.value)


def test_a_lag_that_is_not_on_the_grid_is_an_error():
    with pytest.raises(ConfigError, match="multiple of the grid step"):
        relation(RELATION.replace("lags: [0.0]", "lags: [0.07]"))


LIVENESS = """
type: liveness
topic: /imu
fresh: 1.0
signals:
  - {name: z, field: z, repeats: 5,
     noise: {block: 10, mean: %(mean)s, std: 0.45, cusum: {k: 0.5, h: 10.0}}}
"""


def healthy_log_mean() -> float:
    """ln of the mean squared second difference of 20 Hz samples of the driven signal (white
    noise of std s gives 6 s^2; the slow sine cancels)."""
    return math.log(6 * 0.02 ** 2)


def test_liveness_finds_a_stuck_value_and_a_noise_burst_inside_the_envelope():
    text = LIVENESS % {"mean": healthy_log_mean()}
    obs = liveness_from_config(ConfigNode.parse(text))
    assert drive(obs, 20.0)[-1].code == Code.GENERAL_OK
    for k in range(10):  # frozen
        obs.on_message(msg("/imu", 20.0 + 0.05 * k, z=0.3))
    stuck = obs.evaluate(20.5)[0]
    assert stuck.code == Code.NO_STATE_FITS and "stuck" in stuck.message
    obs = liveness_from_config(ConfigNode.parse(text))
    drive(obs, 20.0)
    burst = drive(obs, 4.0, start=20.0, noise=0.1, seed=3)
    assert any(o.code == Code.NO_STATE_FITS and "noise burst" in o.message for o in burst)


def test_liveness_takes_angle_differences_the_short_way_round():
    # turning at a steady rate cancels in second differences: only the noise is left
    text = (LIVENESS % {"mean": math.log(6 * 0.02 ** 2)}).replace("repeats: 5,",
                                                                  "repeats: 5, wrap: true,")
    obs = liveness_from_config(ConfigNode.parse(text))
    rng = np.random.default_rng(0)
    out = []
    for k in range(600):  # a heading turning through +-pi every few seconds
        t = 0.05 * k
        heading = math.remainder(0.5 * t + rng.normal(0, 0.02), 2 * math.pi)
        obs.on_message(msg("/imu", t, z=heading))
        if k % 20 == 19:
            out.extend(obs.evaluate(t))
    assert all(o.code == Code.GENERAL_OK for o in out[2:]), [o.message for o in out]


def test_the_calibrated_threshold_keeps_gaussian_false_alarms_below_the_rate():
    assert siegmund_arl(threshold_for(1e5)) >= 1e5
    rng = np.random.default_rng(1)
    z = rng.normal(size=2000)
    cal = calibrate(z, blocks_per_hour=7200, rate_per_hour=0.01)
    hours = 20
    assert alarms(rng.normal(size=hours * 7200), cal.h) <= 1


def test_heavy_tails_raise_the_threshold():
    rng = np.random.default_rng(2)
    gauss = calibrate(rng.normal(size=2000), 7200, 0.01)
    heavy = calibrate(rng.standard_t(2, size=2000) / 1.4, 7200, 0.01)
    assert heavy.h > gauss.h


TWO_RELATIONS = RELATION + """  - name: cmd_w
    target: {topic: /cmd, field: w}
    inputs: [{topic: /imu, field: z, lags: [0.0], gains: [1.0]}]
    intercept: 0.0
    block_noise: 0.01
    cusum: {k: 0.5, h: 10.0}
    excitation: 0.02
    span: [-2.0, 2.0]
    clears: false
"""


def test_a_relation_observer_judges_the_fields_it_relates_and_clears_the_targets_of_blind_ones():
    """Field-level (issue 22 item 1): the observer names the (topic, field) signals a
    failure accuses and an OK clears; a relation that cannot see its inputs' faults
    (``clears: false``) still sees its target's, so held it clears its target alone."""
    obs = relation(TWO_RELATIONS)
    judged = obs.judged_signals()
    assert set(judged.accused) == {("/imu", "z"), ("/cmd", "w")}
    assert set(judged.cleared) == {("/imu", "z"), ("/cmd", "w")}  # imu_z sees both
    healthy = drive(obs, 30.0)
    assert healthy[-1].code == Code.GENERAL_OK, healthy[-1].message
    assert "clears /cmd w alone" in healthy[-1].message
    blind = relation(TWO_RELATIONS.replace("imu_z\n", "imu_z\n    clears: false\n", 1))
    assert set(blind.judged_signals().cleared) == {("/imu", "z"), ("/cmd", "w")}
    only_target = relation(RELATION.replace("imu_z\n", "imu_z\n    clears: false\n", 1))
    assert only_target.judged_signals().cleared == (("/imu", "z"),)
    assert drive(only_target, 30.0)[-1].code == Code.GENERAL_OK


# ---- diagnosis ---------------------------------------------------------------------------------

def test_the_pattern_of_failed_and_held_relations_names_the_sensor():
    """Three measurements of one yaw rate: the IMU disagrees with the command and the scan
    matcher, which agree with each other, so the IMU driver alone is the diagnosis."""
    nodes = (NodeSpec("/teleop", ("/cmd",)), NodeSpec("/imu_driver", ("/imu",)),
             NodeSpec("/scan_matcher", ("/scan",)))
    pairs = {("/cmd", "/imu"): False, ("/imu", "/scan"): False, ("/cmd", "/scan"): True}
    specs = [ObservationSpec("relation", Resource(topic=a, topic_b=b)) for a, b in pairs]
    engine = DiagnosisEngine(build_model(nodes, specs))
    d = engine.update(1.0, [Observation(1.0, "relation", Resource(topic=a, topic_b=b),
                                        Code.GENERAL_OK if ok else Code.NO_STATE_FITS)
                            for (a, b), ok in pairs.items()])
    assert d is not None and d.candidates == (frozenset({"/imu_driver"}),)


def test_evidence_building_up_against_a_command_ranks_it_before_the_sensor():
    """A commanded yaw rate and the IMU disagree; nothing else fails, so the command's
    publisher and the IMU driver explain it equally well. The command's other relation (to
    the wheels) has not failed, but its CUSUM is most of the way to its alarm: the
    command ranks first. With that relation at rest the order is the plain tie-break's."""
    nodes = (NodeSpec("/nav", ("/cmd",)), NodeSpec("/imu_driver", ("/imu",)),
             NodeSpec("/wheels", ("/joints",)))
    imu, wheels = Resource(topic="/cmd", topic_b="/imu"), Resource(topic="/cmd",
                                                                   topic_b="/joints")
    specs = [ObservationSpec("relation", imu), ObservationSpec("relation", wheels)]

    def first(wheel_evidence: float) -> frozenset[str]:
        engine = DiagnosisEngine(build_model(nodes, specs))
        d = engine.update(1.0, [
            Observation(1.0, "relation", imu, Code.NO_STATE_FITS,
                        values={"imu_z_evidence": 1.02}),
            Observation(1.0, "relation", wheels, Code.NOT_AVAILABLE,
                        values={"joints_0_evidence": wheel_evidence / 2,
                                "joints_1_evidence": wheel_evidence})])
        assert d is not None and set(d.candidates[:2]) == {frozenset({"/nav"}),
                                                            frozenset({"/imu_driver"})}
        return d.candidates[0]

    assert first(0.7) == frozenset({"/nav"})
    assert first(0.0) == frozenset({"/imu_driver"})


def test_a_relation_reports_its_cusum_as_a_fraction_of_its_alarm_threshold():
    observer = relation()
    held = drive(observer, 30.0)[-1]
    names = [n for n in observer.quantity_names() if n.endswith("_evidence")]
    assert held.code == Code.GENERAL_OK and names
    assert all(0.0 <= held.values[n] < 0.5 for n in names), held.values
    failed = next(o for o in drive(observer, 5.0, start=30.0, offset=0.1, seed=1)
                  if o.code == Code.NO_STATE_FITS)
    assert max(failed.values[n] for n in names) >= 1.0, failed.values


def test_a_passing_learned_envelope_does_not_exonerate_its_producer():
    """Issue 22 item 8: an offset on odometry inside its band, seen downstream only."""
    nodes = (NodeSpec("/odometry", ("/odom",)), NodeSpec("/planner", ("/plan",), ("/odom",)))
    observed = [(ObservationSpec("fields", Resource(topic="/odom")), Code.GENERAL_OK),
                (ObservationSpec("scores", Resource(topic="/plan")), Code.NO_STATE_FITS)]
    engine = DiagnosisEngine(build_model(nodes, [s for s, _ in observed]))
    d = engine.update(1.0, [Observation(1.0, s.type, s.resource, c) for s, c in observed])
    assert d is not None and frozenset({"/odometry"}) in d.candidates


# ---- learning ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def learned_diffdrive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two minutes of the simulated differential-drive robot, as the hidden robot gets."""
    folder = tmp_path_factory.mktemp("learned")
    learned = learn_from(lambda: open_sim("sim:diffdrive", seed=100, realtime=False), 120.0)
    config = folder / "robot.yaml"
    config.write_text(render_config(learned, "robot", "robot.model.yaml", "now"),
                      encoding="utf-8")
    (folder / "robot.model.yaml").write_text(render_model(learned, "now"), encoding="utf-8")
    return config


def test_learning_relates_the_signals_that_measure_the_same_motion(learned_diffdrive: Path):
    loaded = load_config(learned_diffdrive)
    relations = [build_observer(e) for e in loaded.observers if e["type"].str() == "relation"]
    pairs = {(o.resource.topic, o.resource.topic_b) for o in relations}
    assert ("/cmd_yaw", "/imu/data") in pairs or ("/imu/data", "/cmd_yaw") in pairs
    text = learned_diffdrive.read_text(encoding="utf-8")
    assert "held-out R2" in text and "CUSUM k " in text
    assert "type: liveness" in text


@pytest.mark.parametrize("rate,where", [
    ("{at_most: -1.0, period: 1.0}", "signals[0].rate.at_most"),
    ("{at_most: 5.0}", "missing required key 'period'"),
    ("{at_most: 5.0, period: 1.0, fastest: 3}", "signals[0].rate"),
])
def test_a_malformed_rate_bound_names_its_key(rate: str, where: str):
    text = LIVENESS.replace("repeats: 5,", f"repeats: 5, rate: {rate},") % {"mean": -7.0}
    with pytest.raises(ConfigError) as err:
        liveness_from_config(ConfigNode.parse(text))
    assert where in str(err.value)


def test_the_publisher_of_signals_a_held_relation_vouches_for_is_not_closest_to_a_failure():
    """A relation of the command and the wheel speeds fails; the wheel speeds' relation to
    the IMU holds and clears them. The command's publisher reads the wheels (its input), so
    the wheels' publisher explains a wrong command too, across the node: both are single
    candidates. The one whose signal no passing relation vouches for is the closer, and
    ranks first even when evidence short of an alarm builds against the wheels' publisher
    (its own relation of the wheel angles, most of the way to its alarm)."""
    nodes = (NodeSpec("/nav", ("/cmd",), ("/joints",)), NodeSpec("/motor", ("/joints",)),
             NodeSpec("/imu_driver", ("/imu",)))
    cmd_wheels = Resource(topic="/cmd", topic_b="/joints")
    imu_wheels = Resource(topic="/imu", topic_b="/joints")
    angles = Resource(topic="/joints", topic_b="/joints")
    specs = [ObservationSpec("relation", r) for r in (cmd_wheels, imu_wheels, angles)]
    signals = {("relation", cmd_wheels): JudgedSignals((("/cmd", "v"), ("/joints", "v[0]")),
                                                       (("/cmd", "v"), ("/joints", "v[0]"))),
               ("relation", imu_wheels): JudgedSignals((("/imu", "z"), ("/joints", "v[0]")),
                                                       (("/imu", "z"), ("/joints", "v[0]"))),
               ("relation", angles): JudgedSignals((("/joints", "p[0]"), ("/joints", "p[1]")),
                                                   (("/joints", "p[0]"), ("/joints", "p[1]")))}
    engine = DiagnosisEngine(build_model(nodes, specs), signals=signals)
    d = engine.update(1.0, [
        Observation(1.0, "relation", cmd_wheels, Code.NO_STATE_FITS,
                    values={"v_evidence": 1.02}),
        Observation(1.0, "relation", imu_wheels, Code.GENERAL_OK, values={"z_evidence": 0.1}),
        Observation(1.0, "relation", angles, Code.NOT_AVAILABLE, values={"p_evidence": 0.9})])
    assert d is not None
    assert set(d.candidates[:2]) == {frozenset({"/nav"}), frozenset({"/motor"})}, d.candidates
    assert d.candidates[0] == frozenset({"/nav"}), d.candidates
