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

The ROS 2 case shares its robot and learned configuration with test_learn_real_faults.py
(``learned_ros2_diffdrive.py``): one robot, one learning run for both.
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
from blackbox.model import Diagnosis, Observation
from blackbox.observe.build import load_config
from blackbox.sinks import SinkBase
from conftest import black_box_running, wait_for, wait_until
from diffdrive_support import motion_model, ros1_diffdrive
from learned_ros2_diffdrive import GROUP, LEAD, MOTION_SEED, LearnedRobot, learn
from ros2_support import needs_rclpy, ros2_robot

pytestmark = pytest.mark.slow

HELD_WITHIN = 30.0
"""Seconds the black box may take until a relation of the IMU holds (it needs motion)."""
OFFSET = 0.2
"""rad/s added to the IMU's yaw rate: a quarter of its healthy spread or less (asserted)."""
DETECT_WITHIN = 15.0
IMU_DRIVER = "/imu_driver"
VALUE_OBSERVERS = frozenset({"relation", "liveness", "fields"})
RELATION = frozenset({"relation"})
SETTLE = 2.0
"""Seconds after the shared ROS 2 robot's scheduled odometry offset ends before this test's
black box starts, so its relations see only healthy values before the IMU offset."""


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


def yaw_rates(epoch: float, start: float, end: float) -> list[float]:
    """The yaw rate every node of the robot measures, from wall clock ``start`` to ``end``."""
    motion = motion_model.DiffdriveMotion(MOTION_SEED)
    steps = int((end - start) / 0.01)
    return [motion.w(start + i * 0.01 - epoch) for i in range(steps + 1)]


def imu_offset_is_caught_and_blamed_on_the_driver(robot: RealRobot, config: Path,
                                                  learn_start: float, learn_end: float) -> None:
    """The scenario on a robot whose configuration was learned from ``learn_start`` to
    ``learn_end``."""
    relations = [(e["topic"].str(), e["topic_b"].str()) for e in load_config(config).observers
                 if e["type"].str() == "relation"]
    assert any("/imu/data" in pair for pair in relations), \
        f"the IMU related to another topic: {relations}\n{config.read_text()}"

    sink = Collect()
    options = RunOptions(config=config, source=robot.source, live=False, extra_sinks=[sink])
    with black_box_running(options):
        assert wait_for(sink.imu_relation_held, HELD_WITHIN), \
            f"a relation of the IMU held within {HELD_WITHIN:g} s"
        started = min((o.time for o in sink.observations), default=time.time())
        inject = time.time()
        robot.set_yaw_offset(OFFSET)
        try:
            # The first relation to fail may be IMU ~ odometry alone, which cannot tell the
            # IMU from the odometry node (both explain it; on a saturated host the other IMU
            # relations may still be unjudged): the driver must be a suspect from the first
            # such diagnosis and ranked first once the relations tell them apart.
            assert wait_for(lambda: any(d.candidates[0] == {IMU_DRIVER}
                                        for d in sink.accusing(inject, by=RELATION)),
                            DETECT_WITHIN), \
                (f"a diagnosis from a failed relation ranking {IMU_DRIVER} first within "
                 f"{DETECT_WITHIN} s of the IMU offset: "
                 + described(sink.accusing(inject, by=RELATION), inject))
            detected = time.time()
            first = sink.accusing(inject, by=RELATION)[0]
            named = next(d for d in sink.accusing(inject, by=RELATION)
                         if d.candidates[0] == {IMU_DRIVER})
        finally:
            robot.set_yaw_offset(0.0)

    before = sink.accusing(started, inject, by=VALUE_OBSERVERS)
    assert before == [], "no value observer accuses anyone before the offset: " + described(
        before, inject)
    assert any(IMU_DRIVER in c for c in first.candidates), described([first], inject)
    healthy = yaw_rates(robot.epoch, learn_start, learn_end)
    faulty = [w + OFFSET for w in yaw_rates(robot.epoch, inject, detected)]
    spread = max(healthy) - min(healthy)
    assert spread >= 4 * OFFSET, f"offset {OFFSET} is over a quarter of the spread {spread}"
    assert min(healthy) <= min(faulty) and max(faulty) <= max(healthy), \
        "every yaw rate the faulty IMU reported is one it also reports when healthy"
    print(f"{robot.source}: learned in {learn_end - learn_start:.1f} s, relations {relations}, "
          f"detected {first.time - inject:.2f} s after the offset, the IMU driver first "
          f"{named.time - inject:.2f} s after it; healthy yaw rate "
          f"{min(healthy):.3f}..{max(healthy):.3f} rad/s, offset {OFFSET}; diagnoses before "
          f"the offset from timing observers only: {len(sink.accusing(started, inject))}")


@pytest.fixture
def ros1_robot(tmp_path: Path) -> Iterator[ros1_diffdrive.DiffdriveRobot1]:
    robot = ros1_diffdrive.DiffdriveRobot1(ros1_diffdrive.free_port(), log_dir=tmp_path / "logs",
                                           seed=MOTION_SEED, epoch=time.time() - LEAD)
    try:
        yield robot.start()
    finally:
        robot.stop()


@pytest.mark.ros1
@pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")
def test_ros1_a_learned_configuration_names_the_imu_driver_for_an_offset_inside_the_range(
        ros1_robot: ros1_diffdrive.DiffdriveRobot1, tmp_path: Path) -> None:
    source = f"ros1://127.0.0.1:{ros1_robot.port}"
    learn_start = time.time()
    config = learn(source, tmp_path)
    imu_offset_is_caught_and_blamed_on_the_driver(
        RealRobot(source, ros1_robot.epoch, ros1_robot.set_yaw_offset), config, learn_start,
        time.time())


def wait_out_the_scheduled_fault(learned: LearnedRobot) -> None:
    """The shared ROS 2 robot puts an odometry offset on itself at a set motion time (for
    test_learn_real_faults.py): if this test could still be running when it begins, wait
    until it has ended, so no relation of this test's black box sees it."""
    fault = learned.scheduled_fault()
    begins, ends = learned.epoch + fault.start, learned.epoch + fault.end + SETTLE
    needs = HELD_WITHIN + DETECT_WITHIN + 1.0
    if time.time() + needs > begins and time.time() < ends:
        wait_until(lambda: time.time() >= ends, "the shared robot's scheduled odometry offset "
                   "to end", timeout=ends - time.time() + 5.0, step=0.2)


@needs_rclpy
@pytest.mark.ros2
@pytest.mark.xdist_group(GROUP)  # the robot learned once, shared: one worker
def test_ros2_a_learned_configuration_names_the_imu_driver_for_an_offset_inside_the_range(
        learned_ros2_diffdrive: LearnedRobot) -> None:
    learned = learned_ros2_diffdrive
    wait_out_the_scheduled_fault(learned)
    parameters = ros2_robot.ParameterClient(learned.robot.domain_id)
    try:
        imu_offset_is_caught_and_blamed_on_the_driver(
            RealRobot(learned.source, learned.epoch,
                      lambda value: parameters.set(IMU_DRIVER, yaw_offset=value)),
            learned.config, learned.learn_start, learned.learn_end)
    finally:
        parameters.close()
