"""Issue 22's hidden scoring, in small, on real ROS 2: the robot's own seeded fault schedule
(``scripts/robots/diffdrive_faults.py``, the one ``benchmarks/learned_campaign_real.py``
scores) puts an offset on the odometry's forward speed, inside its normal range; a
configuration ``blackbox learn`` wrote from 90 healthy seconds of the same robot finds it
through its relations and the diagnosis names the odometry node first, not its downstream
or upstream neighbours.

The fault is applied by the odometry process itself from the schedule it drew from the
seed, so the test knows when and what without talking to the node, as the campaign does.
The robot, its schedule and the learned configuration are shared with the ROS 2 case of
test_learn_real_imu.py (``learned_ros2_diffdrive.py``): one robot, one learning run.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import pytest

from blackbox.app import RunOptions
from blackbox.model import Diagnosis, Observation
from blackbox.observe.build import load_config
from blackbox.sinks import SinkBase
from conftest import black_box_running, wait_until
from learned_ros2_diffdrive import GROUP, LearnedRobot
from ros2_support import needs_rclpy

pytestmark = [pytest.mark.slow, pytest.mark.ros2,
              pytest.mark.xdist_group(GROUP)]  # the robot learned once, shared: one worker

DETECT_WITHIN = 8.0
ODOMETRY = "/odometry"


class Diagnoses(SinkBase):
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.diagnoses: list[Diagnosis] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        pass

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self.lock:
            self.diagnoses.append(diagnosis)

    def from_relations_on(self, topic: str, since: float) -> list[Diagnosis]:
        """Diagnoses since ``since`` with a failed relation over ``topic``."""
        with self.lock:
            return [d for d in self.diagnoses if d.time >= since and d.candidates
                    and any(o.observer == "relation"
                            and topic in (o.resource.topic, o.resource.topic_b)
                            for o in d.failed)]


@needs_rclpy
def test_ros2_an_odometry_offset_from_the_robots_schedule_is_found_and_named(
        learned_ros2_diffdrive: LearnedRobot) -> None:
    learned = learned_ros2_diffdrive
    fault = learned.scheduled_fault()
    assert (fault.kind, fault.component, fault.field, fault.node) == \
        ("offset", "/odom/twist", "twist.linear.x", ODOMETRY), fault
    begins, ends = learned.epoch + fault.start, learned.epoch + fault.end

    assert learned.learn_end + 5.0 < begins, "learning ended at least 5 s before the fault began"
    source, config = learned.source, learned.config
    relations = [(e["topic"].str(), e["topic_b"].str()) for e in load_config(config).observers
                 if e["type"].str() == "relation"]
    assert any("/odom/twist" in pair for pair in relations), \
        f"a relation over the odometry was learned: {relations}"

    sink = Diagnoses()
    with black_box_running(RunOptions(config=config, source=source, live=False,
                                      extra_sinks=[sink])):
        wait_until(lambda: time.time() >= begins, "the scheduled fault to begin",
                   timeout=begins - time.time() + 5.0, step=0.2)
        found = wait_until(lambda: sink.from_relations_on("/odom/twist", begins),
                           f"a diagnosis from a failed relation over /odom/twist within "
                           f"{DETECT_WITHIN:g} s of the offset", timeout=DETECT_WITHIN)
    first = found[0]  # type: ignore[index]
    assert first.time < ends, "found while the offset lasted"
    assert first.candidates[0] == frozenset({ODOMETRY}), (
        f"{first.time - begins:+.2f} s: {[sorted(c) for c in first.candidates[:3]]} from "
        + ", ".join(f"{o.observer} {o.resource.label()} {o.message!r}" for o in first.failed))
