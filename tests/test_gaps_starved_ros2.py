"""On the real ROS 2 thesis robot (rclpy, Fast DDS): the source finds which watched topics'
publishers run on this host and with which pids (from their participants), and a run-queue
wait of one of them (read from ``schedstat`` files given at the source boundary, mirroring
the robot's real pids) is a gap of that publisher's topic alone, with the host reported
saturated (docs/ros2.md)."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from blackbox.events import Interest, MeasurementGap
from blackbox.model import BlackBoxEvent
from blackbox.sources.cpu_wait import StarvationWatch
from isolation import fresh_domain
from ros2_support import Watched, needs_rclpy, ros2_robot
from test_gaps_starved import write_wait

pytestmark = [pytest.mark.ros2, pytest.mark.slow, needs_rclpy]

TOPICS = {"/audio": "/audio_capture", "/usb_cam/image_raw": "/usb_cam"}


def test_a_local_ros2_publisher_waiting_for_a_cpu_is_a_gap_of_its_topic_alone(
        tmp_path: Path) -> None:
    robot = ros2_robot.ThesisRobot2(fresh_domain(), log_dir=tmp_path / "logs").start(
        list(TOPICS.values()))
    watched: Watched | None = None
    try:
        pids = {n: p for n, p in robot.pids().items() if n in TOPICS.values()}
        assert set(pids) == set(TOPICS.values())
        proc = tmp_path / "proc"
        for pid in pids.values():
            write_wait(proc, pid, 1.0)
        write_wait(proc, "self", 0.0)
        watched = Watched(robot.domain_id, Interest(frozenset(TOPICS)))
        starvation = watched.source.starvation
        starvation.watch = StarvationWatch(proc)
        assert watched.until(lambda: starvation.local_publishers[0] == pids, 60), \
            f"local publishers {starvation.local_publishers} never {pids}"
        assert starvation.local_publishers[1] == {n: (t,) for t, n in TOPICS.items()}
        write_wait(proc, pids["/audio_capture"], 1.4)  # runnable, no core for 0.4 s
        began = len(watched.events)

        def starved() -> list[MeasurementGap]:
            return [e for e in watched.events[began:]
                    if isinstance(e, MeasurementGap) and "host starved" in e.reason]

        def saturated() -> list[BlackBoxEvent]:
            return [e for e in watched.events[began:] if isinstance(e, BlackBoxEvent)
                    and e.kind == "ros2_host_saturated"]
        assert watched.until(lambda: bool(starved()) and bool(saturated()), 10), \
            "no gap and report for the starved publisher"
        assert {g.topic for g in starved()} == {"/audio"}
        assert len(saturated()) == 1 and saturated()[0].component == socket.gethostname()
        assert "/audio_capture" in saturated()[0].message
    finally:
        if watched is not None:
            watched.close()
        robot.stop()
