"""The real ROS 2 correlated-sensor robot (issue 22): its topics through the black box's
ROS 2 source, and an IMU offset injected at run time that stays inside the normal range."""

from __future__ import annotations

import statistics
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.events import Interest
from diffdrive_support import motion_model
from diffdrive_support import ros2_diffdrive as diffdrive_robot
from isolation import fresh_domain
from ros2_support import Watched, needs_rclpy, ros2_robot

DiffdriveMotion = motion_model.DiffdriveMotion


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[diffdrive_robot.DiffdriveRobot2]:
    r = diffdrive_robot.DiffdriveRobot2(fresh_domain(), seed=3, log_dir=tmp_path / "logs")
    try:
        yield r.start()
    finally:
        r.stop()


@needs_rclpy
@pytest.mark.ros2
def test_the_correlated_robot_publishes_one_motion_and_takes_an_imu_offset(robot) -> None:
    topics = frozenset(diffdrive_robot.TOPICS)
    watched = Watched(robot.domain_id, Interest(topics, frozenset({"/imu/data"})))
    injector = ros2_robot.ParameterClient(robot.domain_id)
    motion = DiffdriveMotion(robot.seed)

    def residuals(since: int) -> list[float]:
        return [a.value.angular_velocity.z - motion.w(a.time - robot.epoch)
                for a in watched.arrivals("/imu/data")[since:]]

    try:
        assert watched.until(lambda: all(len(watched.arrivals(t)) >= 20 for t in topics), 30), \
            "every topic of the robot seen 20 times within 30 s"
        graph = watched.graphs()[-1]
        assert {t: graph.topics[t].publishers for t in topics} == {
            t: (n,) for t, n in diffdrive_robot.TOPICS.items()}
        healthy = residuals(0)
        assert abs(statistics.mean(healthy)) < 0.05      # the IMU measures the shared yaw rate
        injector.set("/imu_driver", yaw_offset=0.2)
        mark = len(watched.arrivals("/imu/data"))
        assert watched.until(lambda: len(residuals(mark)) >= 200, 10), "200 IMU samples after"
        shifted = residuals(mark)[50:]                    # after the parameter took effect
        assert statistics.mean(shifted) == pytest.approx(0.2, abs=0.05)
    finally:
        injector.close()
        watched.close()
