"""Issue 22 on real middlewares: a configuration learned by `blackbox learn` from a short
healthy run of the real diffdrive robot (rospy on ROS 1, rclpy on ROS 2) catches an IMU yaw
offset that never leaves the yaw rate's healthy range, and the diagnosis from the failed
relations names the IMU driver first; before the offset, no value observer accuses anyone.

No envelope can see such an offset (every faulty value is one the IMU also reports when
healthy); only the learned relations between the IMU, the command and the odometry can.

"Accuses no one before" is judged on the value observers (relations, liveness, envelopes):
the learned rate, age and time-out bounds measure the robot's processes, which a shared
2-core test machine under load really slows, all topics at once (seen: every topic at
60-80 % of its rate for a second while other tests ran). Those diagnoses are about the
machine, not about relations, and are counted in the printed summary instead.
"""

from __future__ import annotations

import shutil
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

from blackbox.app import RunOptions
from blackbox.events import Interest
from blackbox.learn import learn_from, render_config, render_model
from blackbox.model import Diagnosis, Observation
from blackbox.observe.build import load_config
from blackbox.sinks import SinkBase
from blackbox.sources import open_source
from conftest import black_box_running, wait_for
from diffdrive_support import motion_model, ros1_diffdrive, ros2_diffdrive
from isolation import fresh_domain
from ros2_support import Watched, needs_rclpy, ros2_robot

pytestmark = pytest.mark.slow

SEED = 5
LEAD = 5.0
"""The robots' motion starts this many seconds into its script (seed 5), so that the
learning run sees it go straight, turn, stand, go straight, stand and turn, with a turn in
the held-out last 30 %, and is followed by more than 30 s of driving without standing
still (standing still is unjudged when learning saw less than 20 s of it)."""
LEARN_SECONDS = 90.0
"""With 60 s (a window starting 30 s later), one ROS 1 run of nine learned no relation of the
IMU and three learned only one (the loaded rospy IMU comes in bursts); 90 s learned all
five relations in six of six runs."""
OFFSET = 0.2
"""rad/s added to the IMU's yaw rate: a quarter of its healthy spread or less (asserted)."""
DETECT_WITHIN = 15.0
IMU_DRIVER = "/imu_driver"
VALUE_OBSERVERS = frozenset({"relation", "liveness", "fields"})
RELATION = frozenset({"relation"})


class Collect(SinkBase):
    """Every observation and diagnosis of the black box running in a test thread."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.observations: list[Observation] = []
        self.diagnoses: list[Diagnosis] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self.lock:
            self.observations.extend(observations)

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self.lock:
            self.diagnoses.append(diagnosis)

    def imu_relation_held(self) -> bool:
        """A relation with the IMU on one side judged OK (the relations see motion)."""
        with self.lock:
            return any(o.observer == "relation" and not o.faulty
                       and "/imu/data" in (o.resource.topic, o.resource.topic_b)
                       for o in self.observations)

    def accusing(self, since: float, until: float = float("inf"),
                 by: frozenset[str] | None = None) -> list[Diagnosis]:
        """Diagnoses naming candidates in [since, until), only those with a failed
        observation of an observer type in ``by`` if given."""
        with self.lock:
            return [d for d in self.diagnoses if since <= d.time < until and d.candidates
                    and (by is None or any(o.observer in by for o in d.failed))]


def described(diagnoses: Sequence[Diagnosis], since: float) -> str:
    """The diagnoses with what failed, for an assertion message."""
    return "; ".join(
        f"at {d.time - since:+.2f} s {[sorted(c) for c in d.candidates[:3]]} from "
        + ", ".join(f"{o.observer} {o.resource.label()} {o.code.name} {o.message!r}"
                    for o in d.failed)
        for d in diagnoses[:5])


@dataclass
class RealRobot:
    """What the scenario needs of either robot: its source spec and the IMU offset knob."""

    source: str
    epoch: float
    set_yaw_offset: Callable[[float], None]


def learn(source: str, out: Path) -> Path:
    learned = learn_from(lambda: open_source(source), LEARN_SECONDS)
    config = out / "robot.yaml"
    config.write_text(render_config(learned, "robot", "robot.model.yaml", "test"),
                      encoding="utf-8")
    (out / "robot.model.yaml").write_text(render_model(learned, "test"), encoding="utf-8")
    return config


def yaw_rates(epoch: float, start: float, end: float) -> list[float]:
    """The yaw rate every node of the robot measures, from wall clock ``start`` to ``end``."""
    motion = motion_model.DiffdriveMotion(SEED)
    steps = int((end - start) / 0.01)
    return [motion.w(start + i * 0.01 - epoch) for i in range(steps + 1)]


def imu_offset_is_caught_and_blamed_on_the_driver(robot: RealRobot, tmp_path: Path) -> None:
    learn_start = time.time()
    config = learn(robot.source, tmp_path)
    learn_end = time.time()
    relations = [(e["topic"].str(), e["topic_b"].str()) for e in load_config(config).observers
                 if e["type"].str() == "relation"]
    assert any("/imu/data" in pair for pair in relations), \
        f"the IMU related to another topic: {relations}\n{config.read_text()}"

    sink = Collect()
    options = RunOptions(config=config, source=robot.source, live=False, extra_sinks=[sink])
    with black_box_running(options):
        assert wait_for(sink.imu_relation_held, 30), "a relation of the IMU held within 30 s"
        started = min((o.time for o in sink.observations), default=time.time())
        inject = time.time()
        robot.set_yaw_offset(OFFSET)
        try:
            assert wait_for(lambda: bool(sink.accusing(inject, by=RELATION)), DETECT_WITHIN), \
                f"a diagnosis from a failed relation within {DETECT_WITHIN} s of the IMU offset"
            first = sink.accusing(inject, by=RELATION)[0]
            detected = time.time()
        finally:
            robot.set_yaw_offset(0.0)

    before = sink.accusing(started, inject, by=VALUE_OBSERVERS)
    assert before == [], "no value observer accuses anyone before the offset: " + described(
        before, inject)
    assert first.candidates[0] == frozenset({IMU_DRIVER}), described([first], inject)
    healthy = yaw_rates(robot.epoch, learn_start, learn_end)
    faulty = [w + OFFSET for w in yaw_rates(robot.epoch, inject, detected)]
    spread = max(healthy) - min(healthy)
    assert spread >= 4 * OFFSET, f"offset {OFFSET} is over a quarter of the spread {spread}"
    assert min(healthy) <= min(faulty) and max(faulty) <= max(healthy), \
        "every yaw rate the faulty IMU reported is one it also reports when healthy"
    print(f"{robot.source}: learned in {learn_end - learn_start:.1f} s, relations {relations}, "
          f"detected {first.time - inject:.2f} s after the offset; healthy yaw rate "
          f"{min(healthy):.3f}..{max(healthy):.3f} rad/s, offset {OFFSET}; diagnoses before "
          f"the offset from timing observers only: {len(sink.accusing(started, inject))}")


@pytest.fixture
def ros1_robot(tmp_path: Path) -> Iterator[ros1_diffdrive.DiffdriveRobot1]:
    robot = ros1_diffdrive.DiffdriveRobot1(ros1_diffdrive.free_port(), log_dir=tmp_path / "logs",
                                           seed=SEED, epoch=time.time() - LEAD)
    try:
        yield robot.start()
    finally:
        robot.stop()


@pytest.mark.ros1
@pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")
def test_ros1_a_learned_configuration_names_the_imu_driver_for_an_offset_inside_the_range(
        ros1_robot: ros1_diffdrive.DiffdriveRobot1, tmp_path: Path) -> None:
    imu_offset_is_caught_and_blamed_on_the_driver(
        RealRobot(f"ros1://127.0.0.1:{ros1_robot.port}", ros1_robot.epoch,
                  ros1_robot.set_yaw_offset), tmp_path)


@pytest.fixture
def ros2_robot_running(tmp_path: Path) -> Iterator[ros2_diffdrive.DiffdriveRobot2]:
    robot = ros2_diffdrive.DiffdriveRobot2(fresh_domain(), seed=SEED, log_dir=tmp_path / "logs",
                                           epoch=time.time() - LEAD)
    try:
        robot.start()
        # Learning watches a running robot: wait until every node publishes (rclpy nodes
        # take seconds to start here), or discovery sees only part of the graph.
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
@pytest.mark.ros2
def test_ros2_a_learned_configuration_names_the_imu_driver_for_an_offset_inside_the_range(
        ros2_robot_running: ros2_diffdrive.DiffdriveRobot2, tmp_path: Path) -> None:
    robot = ros2_robot_running
    parameters = ros2_robot.ParameterClient(robot.domain_id)
    try:
        imu_offset_is_caught_and_blamed_on_the_driver(
            RealRobot(f"ros2:{robot.domain_id}", robot.epoch,
                      lambda value: parameters.set(IMU_DRIVER, yaw_offset=value)), tmp_path)
    finally:
        parameters.close()
