"""On the real ROS 1 thesis robot: the source finds which watched topics' publishers run on
this host and with which pids, and a run-queue wait of one of them (read from ``schedstat``
files given at the source boundary, mirroring the robot's real pids) is a gap of that
publisher's topics alone, with the host reported saturated (docs/ros1.md)."""

from __future__ import annotations

import shutil
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.events import Interest, MeasurementGap
from blackbox.model import BlackBoxEvent
from blackbox.sources.cpu_wait import StarvationWatch
from blackbox.sources.ros1.source import Ros1Source
from ros1_watch import Watch
from test_gaps_starved import write_wait

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from robot import ThesisRobot, free_port

pytestmark = [pytest.mark.ros1, pytest.mark.slow,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

TOPICS = {"/audio": "/audio_capture", "/usb_cam/image_raw": "/usb_cam",
          "/signal": "/Signal_generator"}


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[ThesisRobot]:
    r = ThesisRobot(free_port(), log_dir=tmp_path / "logs")
    try:
        yield r.start()
    finally:
        r.stop()


def test_a_local_publisher_waiting_for_a_cpu_is_a_gap_of_its_topics_alone(
        robot: ThesisRobot, tmp_path: Path) -> None:
    source = Ros1Source(f"http://127.0.0.1:{robot.port}")
    source.starvation.watch = StarvationWatch(tmp_path)
    pids = {node: robot.pid(node) for node in TOPICS.values()}
    for pid in pids.values():
        write_wait(tmp_path, pid, 1.0)
    write_wait(tmp_path, "self", 0.0)
    source.start(Interest(topics=frozenset(TOPICS), decoded=frozenset({"/signal"})))
    watch = Watch(source)
    try:
        assert watch.until(lambda: source.starvation.local_publishers[0] == pids, 30), \
            f"local publishers {source.starvation.local_publishers} never {pids}"
        assert source.starvation.local_publishers[1] == {
            node: (topic,) for topic, node in TOPICS.items()}
        assert not watch.until(lambda: any(isinstance(e, MeasurementGap) and
                                           "starved" in e.reason for e in watch.events), 1.5)
        write_wait(tmp_path, pids["/audio_capture"], 1.4)  # runnable, no core for 0.4 s
        began = len(watch.events)

        def starved() -> list[MeasurementGap]:
            return [e for e in watch.events[began:]
                    if isinstance(e, MeasurementGap) and "host starved" in e.reason]
        assert watch.until(lambda: bool(starved()), 5), "no gap for the starved publisher"
        assert {g.topic for g in starved()} == {"/audio"}
        assert all(g.end is not None and g.end - g.start <= 1.5 for g in starved())

        def saturated() -> list[BlackBoxEvent]:
            return [e for e in watch.events[began:] if isinstance(e, BlackBoxEvent)
                    and e.kind == "ros1_host_saturated"]
        assert watch.until(lambda: bool(saturated()), 5), "the host was not reported"
        assert len(saturated()) == 1 and saturated()[0].component == socket.gethostname()
        assert "/audio_capture" in saturated()[0].message
        quiet = time.time() + 1.5  # the wait window (1 s) passed: judged again
        assert watch.until(lambda: time.time() > quiet, 5)
        after = len(watch.events)
        assert not watch.until(lambda: any(isinstance(e, MeasurementGap) and "starved" in
                                           e.reason for e in watch.events[after:]), 1.5)
    finally:
        source.close()
