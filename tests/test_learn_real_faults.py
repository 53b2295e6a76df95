"""Issue 22's hidden scoring, in small, on real ROS 2: the robot's own seeded fault schedule
(``scripts/robots/diffdrive_faults.py``, the one ``benchmarks/learned_campaign_real.py``
scores) puts an offset on the odometry's forward speed, inside its normal range; a
configuration ``blackbox learn`` wrote from 90 healthy seconds of the same robot finds it
through its relations and the diagnosis names the odometry node first, not its downstream
or upstream neighbours.

The fault is applied by the odometry process itself from the schedule it drew from the
seed, so the test knows when and what without talking to the node, as the campaign does.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from blackbox.app import RunOptions
from blackbox.events import Interest
from blackbox.learn import learn_from, render_config, render_model
from blackbox.model import Diagnosis, Observation
from blackbox.observe.build import load_config
from blackbox.sinks import SinkBase
from blackbox.sources import open_source
from conftest import black_box_running, wait_until
from diffdrive_support import SCRIPTS, load_script, ros2_diffdrive
from isolation import fresh_domain
from ros2_support import Watched, needs_rclpy

faults_model = load_script(SCRIPTS / "robots" / "diffdrive_faults.py", "diffdrive_faults")

pytestmark = [pytest.mark.slow, pytest.mark.ros2,
              pytest.mark.xdist_group("test_learn_real_faults")]  # a real robot: one worker

MOTION_SEED = 5
"""The motion script of the real-middleware tests: learning from motion second ~10 on sees
it go straight, stand, turn and go straight (test_learn_real_imu.py)."""
LEAD = 5.0
LEARN_SECONDS = 90.0
FAULT_SEED = 204
"""Its schedule's only fault in the first 25 s: an offset of 0.132 m/s (8.8 times the
odometry's noise) on ``/odom/twist`` ``twist.linear.x``, 7.7 s after the schedule starts."""
SCHEDULE_START = 143.0
"""Motion second the schedule starts at: the offset falls at 150.7-159.8 s, while the robot
goes straight (148.8-174.4 s for motion seed 5), and leaves the robot 37 s to start before
learning (5 + 37 + 90 + 10 s of settling = 142 s)."""
SCHEDULE_LENGTH = 25.0
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


@pytest.fixture
def faulty_robot(tmp_path: Path) -> Iterator[ros2_diffdrive.DiffdriveRobot2]:
    robot = ros2_diffdrive.DiffdriveRobot2(
        fresh_domain(), seed=MOTION_SEED, log_dir=tmp_path / "logs", epoch=time.time() - LEAD,
        faults=(FAULT_SEED, SCHEDULE_START, SCHEDULE_LENGTH))
    try:
        robot.start()
        topics = frozenset(ros2_diffdrive.TOPICS)
        watched = Watched(robot.domain_id, Interest(topics))
        try:
            assert watched.until(lambda: all(watched.arrivals(t) for t in topics), 90), \
                "every topic of the ROS 2 robot publishing within 90 s"
        finally:
            watched.close()
        yield robot
    finally:
        robot.stop()


@needs_rclpy
def test_ros2_an_odometry_offset_from_the_robots_schedule_is_found_and_named(
        faulty_robot: ros2_diffdrive.DiffdriveRobot2, tmp_path: Path) -> None:
    robot = faulty_robot
    (fault,) = faults_model.schedule(FAULT_SEED, SCHEDULE_START, SCHEDULE_LENGTH)
    assert (fault.kind, fault.component, fault.field, fault.node) == \
        ("offset", "/odom/twist", "twist.linear.x", ODOMETRY), fault
    begins, ends = robot.epoch + fault.start, robot.epoch + fault.end

    source = f"ros2:{robot.domain_id}"
    learned = learn_from(lambda: open_source(source), LEARN_SECONDS)
    assert time.time() + 5.0 < begins, "learning ended at least 5 s before the fault began"
    config = tmp_path / "robot.yaml"
    config.write_text(render_config(learned, "robot", "robot.model.yaml", "test"),
                      encoding="utf-8")
    (tmp_path / "robot.model.yaml").write_text(render_model(learned, "test"), encoding="utf-8")
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
