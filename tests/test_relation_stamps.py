"""A learned relation times a stamped signal by its header stamp, not by its arrival: a
publisher that is late for seconds (a loaded robot computer) is no lie about the motion."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blackbox.events import MessageArrival
from blackbox.model import Code
from blackbox.observe.signals import STAMP_LIMIT, sample_time
from test_learn_relations_bad_input import (
    Cmd,
    graph,
    judge,
    learned_text,
    observer_from,
    relations_of,
    yaw,
)


@dataclass(frozen=True)
class Stamp:
    sec: int
    nanosec: int


@dataclass(frozen=True)
class Header:
    stamp: Stamp


@dataclass(frozen=True)
class StampedImu:
    header: Header
    z: float


def stamped(t: float) -> Header:
    sec = math.floor(t)
    return Header(Stamp(sec, round((t - sec) * 1e9)))


def robot(seconds: float, *, seed: int, late: float = 0.0) -> list:
    """A command and an IMU measuring one yaw rate; the IMU stamps each sample when it
    measures it and, in every other stretch of 8 s, delivers it ``late`` seconds after."""
    rng = np.random.default_rng(seed)
    events: list = [graph(float(t)) for t in range(int(seconds) + 1)]
    for k in range(int(seconds * 20)):
        t = k / 20 + 0.003
        w = yaw(t)
        events.append(MessageArrival(t, "/cmd", "/teleop", 8,
                                     value=Cmd(w + rng.normal(0, 0.005))))
        delay = 0.002 + (late if int(t / 8) % 2 else 0.0)
        events.append(MessageArrival(t + delay, "/imu", "/imu_driver", 8,
                                     value=StampedImu(stamped(t), w + rng.normal(0, 0.02))))
    return sorted(events, key=lambda e: e.time)


def test_a_sample_is_timed_by_its_stamp_when_the_stamp_is_near_its_arrival() -> None:
    assert sample_time(10.05, 10.0) == 10.0
    assert sample_time(10.0, 0.0) == 10.0  # no stamp
    assert sample_time(10.0, None) == 10.0
    assert sample_time(100.0, 100.0 - 2 * STAMP_LIMIT) == 100.0  # another clock


def test_a_publisher_late_for_seconds_is_no_relation_fault() -> None:
    _, text = learned_text(robot(120.0, seed=1), 120.0)
    [entry] = relations_of(text)
    assert entry["stamps"] == {"/imu": "header.stamp"}
    late = judge(observer_from(text), robot(240.0, seed=2, late=0.06), 240.0)
    assert sum(o.code == Code.GENERAL_OK for o in late) > 150
    assert [o.message for o in late if o.code == Code.NO_STATE_FITS] == []


def test_a_lie_is_still_one_when_samples_are_timed_by_their_stamps() -> None:
    _, text = learned_text(robot(120.0, seed=1), 120.0)
    lie = robot(200.0, seed=3)
    lie = [MessageArrival(e.time, e.topic, e.publisher, e.size,
                          value=StampedImu(e.value.header, e.value.z + 0.15))
           if isinstance(e, MessageArrival) and e.topic == "/imu" and e.time > 100 else e
           for e in lie]
    failed = [o.time for o in judge(observer_from(text), lie, 200.0)
              if o.code == Code.NO_STATE_FITS]
    assert failed and 100.0 < failed[0] <= 103.0, failed[:3]
