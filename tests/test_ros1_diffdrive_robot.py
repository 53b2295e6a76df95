"""The real ROS 1 correlated-sensor robot (issue 22): every topic reaches the black box's
ROS 1 source from the node that publishes it, all nodes measure one motion, and an IMU
offset injected at run time (one ``setParam``) shifts the reported yaw rate by exactly that."""

from __future__ import annotations

import shutil
import statistics
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from blackbox.events import GraphSnapshot, Interest, MessageArrival
from blackbox.sources.ros1 import Ros1Source
from diffdrive_support import motion_model, ros1_diffdrive

pytestmark = [pytest.mark.ros1,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

TOPICS: dict[str, str] = ros1_diffdrive.TOPICS


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[ros1_diffdrive.DiffdriveRobot1]:
    r = ros1_diffdrive.DiffdriveRobot1(ros1_diffdrive.free_port(), log_dir=tmp_path / "logs",
                                       seed=3)
    try:
        yield r.start()
    finally:
        r.stop()


class Watch:
    """A started :class:`Ros1Source` whose events the test polls and keeps."""

    def __init__(self, source: Ros1Source) -> None:
        self.source = source
        self.events: list[object] = []

    def until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.events.extend(self.source.poll(time.time() + 0.05))
            if condition():
                return True
        return bool(condition())

    def arrivals(self, topic: str) -> list[MessageArrival]:
        return [e for e in self.events if isinstance(e, MessageArrival) and e.topic == topic]

    def graphs(self) -> list[GraphSnapshot]:
        return [e for e in self.events if isinstance(e, GraphSnapshot)]


def test_every_topic_comes_from_its_driver_and_the_imu_takes_an_offset_at_run_time(
        robot: ros1_diffdrive.DiffdriveRobot1) -> None:
    topics = frozenset(TOPICS)
    source = Ros1Source(robot.master_uri)
    source.start(Interest(topics, frozenset(topics)))
    watch = Watch(source)
    motion = motion_model.DiffdriveMotion(robot.seed)

    def imu_residuals(since: float = 0.0) -> list[float]:
        """Reported minus true yaw rate of the IMU messages stamped at or after ``since``
        (the stamp, not the arrival: a loaded machine delivers late)."""
        out = []
        for a in watch.arrivals("/imu/data"):
            stamp = a.value.header.stamp.sec + a.value.header.stamp.nanosec * 1e-9
            if stamp >= since:
                out.append(a.value.angular_velocity.z - motion.w(stamp - robot.epoch))
        return out

    try:
        assert watch.until(lambda: all(len(watch.arrivals(t)) >= 20 for t in topics), 30), \
            "every topic of the robot seen 20 times within 30 s"
        graph = watch.graphs()[-1]
        assert {t: graph.topics[t].publishers for t in topics} == {
            t: (n,) for t, n in TOPICS.items()}
        assert "/base_driver" in graph.topics["/cmd_vel"].subscribers
        assert "/odometry" in graph.topics["/joint_states"].subscribers
        assert {(a.topic, a.publisher) for t in topics for a in watch.arrivals(t)} == set(
            TOPICS.items()), "each message is attributed to the node that sent it"
        cmd = watch.arrivals("/cmd_vel")
        assert statistics.mean(a.value.angular.z - motion.w(a.time - robot.epoch)
                               for a in cmd) == pytest.approx(0.0, abs=0.05)
        assert abs(statistics.mean(imu_residuals())) < 0.05   # one shared yaw rate

        robot.set_yaw_offset(0.2)
        settled = time.time() + 1.0                            # the parameter cache has it
        assert watch.until(lambda: len(imu_residuals(settled)) >= 100, 15), \
            "100 IMU samples stamped 1 s after setting the offset, within 15 s"
        assert statistics.mean(imu_residuals(settled)) == pytest.approx(0.2, abs=0.05)
    finally:
        source.close()
