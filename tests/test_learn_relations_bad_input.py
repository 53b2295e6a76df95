"""Learning relations from input that does not behave (issue 22 item 9), and judging with
them: a measurement gap, too little data, NaN and inf, a quantised signal, a topic that
starts late, a changed rate. Each has a defined, documented outcome; none raises and none
gives a silent false alarm."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blackbox.events import GraphSnapshot, MeasurementGap, MessageArrival, NodeInfo, TopicInfo
from blackbox.learn import Learned, learn_from, render_config
from blackbox.learn.recording import record
from blackbox.learn.relations import learn_relations
from blackbox.model import Code
from blackbox.observe.build import load_config_text
from blackbox.observe.observers.relation import RelationObserver
from blackbox.sources.memory import MemorySource

TOPICS = {"/cmd": ("/teleop", "w"), "/imu": ("/imu_driver", "z")}


@dataclass(frozen=True)
class Cmd:
    w: float


@dataclass(frozen=True)
class Imu:
    z: float


def graph(t: float) -> GraphSnapshot:
    nodes = {n: NodeInfo(n, True, 100 + i) for i, (n, _) in enumerate(TOPICS.values())}
    topics = {t_: TopicInfo(t_, "std_msgs/Float64", (n,), ()) for t_, (n, _) in TOPICS.items()}
    return GraphSnapshot(t, nodes, topics)


def yaw(t: float) -> float:
    """A yaw rate that moves (turning left and right)."""
    return 0.5 * math.sin(2 * math.pi * t / 7.0) + 0.3 * math.sin(2 * math.pi * t / 3.1)


def robot(seconds: float, *, rate: float = 20.0, seed: int = 0, imu=None, cmd_from: float = 0.0,
          extra: list | None = None) -> list:
    """Events of a command and an IMU measuring one yaw rate (``imu(t, w)`` may lie)."""
    rng = np.random.default_rng(seed)
    events: list = [graph(float(t)) for t in range(int(seconds) + 1)]
    k = 0
    while k / rate < seconds:
        t = k / rate + 0.003
        w = yaw(t)
        if t >= cmd_from:
            events.append(MessageArrival(t, "/cmd", "/teleop", 8,
                                         value=Cmd(w + rng.normal(0, 0.005))))
        z = w + rng.normal(0, 0.02)
        events.append(MessageArrival(t + 0.011, "/imu", "/imu_driver", 8,
                                     value=Imu(z if imu is None else imu(t, z))))
        k += 1
    return sorted(events + (extra or []), key=lambda e: e.time)


def learned_text(events: list, seconds: float) -> tuple[Learned, str]:
    learned = learn_from(lambda: MemorySource(events), seconds)
    text = render_config(learned, "r", "r.model.yaml", "now")
    load_config_text(text, "r.yaml")  # it loads
    return learned, text


def relations_of(text: str) -> list[dict]:
    config = load_config_text(text, "r.yaml")
    return [e.to_python() for e in config.observers if e.to_python()["type"] == "relation"]


def test_a_measurement_gap_is_not_learned_from() -> None:
    """Inside a gap the IMU says 50 (the reader replaying garbage); learning skips it, so the
    relation is learned as if the gap were not there."""
    gap = MeasurementGap(40.0, 40.0, 50.0, "paused", topic="/imu")
    events = robot(120.0, imu=lambda t, z: 50.0 if 40.0 <= t <= 50.0 else z, extra=[gap])
    _, text = learned_text(events, 120.0)
    rels = relations_of(text)
    assert rels, text
    assert "message(s) inside measurement gaps not learned from" in text
    span = rels[0]["relations"][0]["span"]
    assert span[1] < 5.0  # the garbage never reached the fit


def test_a_starved_publishers_values_are_learned_from_and_its_periods_are_not() -> None:
    """A loaded computer starves the IMU driver for most of the run: its starvation gaps
    are timing-only, so the relation is learned from its values all the same, while the
    same stretch as an ordinary gap leaves too little to learn from."""
    starved = [MeasurementGap(t, t, t + 1.0, "the host starved /imu_driver",
                              topic="/imu", timing_only=True) for t in range(10, 110, 2)]
    _, text = learned_text(robot(120.0, extra=starved), 120.0)
    assert relations_of(text), text
    assert "inside measurement gaps not learned from" not in text
    assert "gap(s) while a publisher was not running" in text  # its periods were dropped

    blind = [MeasurementGap(t, t, t + 1.0, "paused", topic="/imu")
             for t in range(10, 110, 2)]
    _, text = learned_text(robot(120.0, extra=blind), 120.0)
    assert "inside measurement gaps not learned from" in text


def test_too_little_healthy_data_for_a_relation_is_said_not_guessed() -> None:
    _, text = learned_text(robot(20.0), 20.0)
    assert relations_of(text) == []
    assert "no relation between signals" in text and "in 20 s" in text


def test_nan_and_inf_while_learning_are_skipped_and_the_relation_still_learned() -> None:
    def broken(t: float, z: float) -> float:
        k = int(t * 20)
        return math.nan if k % 17 == 0 else math.inf if k % 23 == 0 else z
    _, text = learned_text(robot(120.0, imu=broken), 120.0)
    assert relations_of(text)


def test_a_quantised_signal_gets_no_stuck_check_it_would_fail() -> None:
    """An IMU that reports multiples of 0.05 repeats itself while healthy: no stuck check,
    but its noise is still learned (from the blocks that change)."""
    events = robot(120.0, imu=lambda t, z: round(z * 20) / 20)
    rec = record(MemorySource(events), graph(0.0), 120.0)
    lives = learn_relations(rec).liveness["/imu"]
    assert lives[0].repeats is None and lives[0].longest_run > 3
    assert lives[0].z is not None


def test_a_topic_that_starts_late_is_related_over_the_time_both_ran() -> None:
    _, text = learned_text(robot(150.0, cmd_from=40.0), 150.0)
    assert relations_of(text)


def observer_from(text: str) -> RelationObserver:
    from blackbox.observe.build import build_observer

    entry = load_config_text(text, "r.yaml").observers
    rel = next(e for e in entry if e.to_python()["type"] == "relation")
    obs = build_observer(rel)
    assert isinstance(obs, RelationObserver)
    return obs


def judge(obs: RelationObserver, events: list, until: float) -> list:
    out = []
    next_eval = 1.0
    for e in events:
        if not isinstance(e, MessageArrival):
            continue
        while e.time >= next_eval:
            out.extend(obs.evaluate(next_eval))
            next_eval += 1.0
        obs.on_message(e)
    return out


def test_a_changed_rate_is_no_fault_and_a_lie_still_is() -> None:
    """Learned at 20 Hz, judged at 10 Hz: the grid puts both on the same footing."""
    _, text = learned_text(robot(120.0, seed=1), 120.0)
    slower = judge(observer_from(text), robot(200.0, rate=10.0, seed=2), 200.0)
    assert all(o.code != Code.NO_STATE_FITS for o in slower), [o.message for o in slower
                                                               if o.code == Code.NO_STATE_FITS]
    assert sum(o.code == Code.GENERAL_OK for o in slower) > 150
    lying = judge(observer_from(text),
                  robot(200.0, rate=10.0, seed=3, imu=lambda t, z: z + (0.15 if t > 100 else 0)),
                  200.0)
    failed = [o.time for o in lying if o.code == Code.NO_STATE_FITS]
    assert failed and 100.0 < failed[0] <= 103.0, failed[:3]


def test_a_signal_that_stops_leaves_the_relation_unjudged_not_failed() -> None:
    _, text = learned_text(robot(120.0, seed=1), 120.0)
    events = [e for e in robot(100.0, seed=4)
              if not (isinstance(e, MessageArrival) and e.topic == "/imu" and e.time > 60.0)]
    out = judge(observer_from(text), events, 100.0)
    after = [o for o in out if o.time > 62.0]
    assert after and all(o.code == Code.NOT_AVAILABLE for o in after)
    assert "stale" in after[-1].message or "waiting" in after[-1].message


def test_samples_that_arrive_in_bursts_are_learned_not_a_crash() -> None:
    """Seen on a loaded machine (real ROS 1): most IMU samples reached the learner in
    bursts with one receive time each, so the median period was zero, which divided.
    The mean period stands in; the relation and the liveness are still learned."""
    events = robot(120.0)
    bursty = [MessageArrival(math.floor(e.time * 4) / 4, e.topic, e.publisher, e.size,
                             value=e.value)
              if isinstance(e, MessageArrival) and e.topic == "/imu" else e for e in events]
    rec = record(MemorySource(sorted(bursty, key=lambda e: e.time)), graph(0.0), 120.0)
    learned = learn_relations(rec)
    imu = [live for live in learned.liveness.get("/imu", [])]
    assert all(live.signal.period > 0 for live in imu)
    assert all(live.calibration is not None for live in imu if live.z is not None)


def test_a_slow_signal_with_too_few_samples_is_not_related_and_says_why() -> None:
    """Two minutes of a 0.4 Hz IMU: 48 samples are too few to fit a relation, let alone
    calibrate its threshold (slower signals with more samples: test_learn_slow_signals)."""
    _, text = learned_text(robot(120.0, rate=0.4), 120.0)
    assert relations_of(text) == []
    assert "fewer than 60 samples while learning, not related" in text
    assert "/imu z" in text.split("fewer than 60")[0].splitlines()[-1]
