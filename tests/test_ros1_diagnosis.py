"""Diagnosis on the real thesis robot (Debian ROS 1): a SIGKILLed camera driver is the single
diagnosis, not the downstream symptoms; a wrong signal value blames the signal generator."""

from __future__ import annotations

import shutil
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.app import DEFAULT_CONFIG, RunOptions
from blackbox.model import Diagnosis
from blackbox.sinks import SinkBase
from conftest import black_box_running, wait_for

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from inject import Injector
from robot import ThesisRobot, free_port

pytestmark = [pytest.mark.ros1, pytest.mark.slow,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]


class Diagnoses(SinkBase):
    def __init__(self) -> None:
        self.records: list[Diagnosis] = []
        self.lock = threading.Lock()

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self.lock:
            self.records.append(diagnosis)

    def latest(self) -> Diagnosis | None:
        with self.lock:
            return self.records[-1] if self.records else None



@pytest.fixture
def running(tmp_path: Path) -> Iterator[tuple[ThesisRobot, Diagnoses]]:
    robot = ThesisRobot(free_port(), log_dir=tmp_path / "logs").start()
    sink = Diagnoses()
    # The shipped thesis observers (windows of 50): the diagnosis must not depend on tuning.
    # Subscriptions for every rate, so a kill fails activated, timeout and hz in one round
    # (rates from the publishers' counters come one graph round later; docs/ros1.md).
    options = RunOptions(config=DEFAULT_CONFIG,
                         source=f"ros1://127.0.0.1:{robot.port}?counters=0",
                         live=False, extra_sinks=[sink])
    try:
        with black_box_running(options):
            yield robot, sink
    finally:
        robot.stop()

def healthy(sink: Diagnoses) -> bool:
    latest = sink.latest()
    return latest is not None and not latest.failed


def test_killed_camera_driver_and_wrong_signal_are_isolated(
        running: tuple[ThesisRobot, Diagnoses]) -> None:
    robot, sink = running
    injector = Injector(robot)
    assert wait_for(lambda: healthy(sink), 30), f"never healthy: {sink.latest()}"

    fault = injector.begin("kill", "/usb_cam")
    assert wait_for(lambda: (d := sink.latest()) is not None and len(d.failed) >= 3, 5)
    killed = sink.latest()
    injector.end(fault)
    robot.wait_registered(["/usb_cam"])
    assert killed is not None and killed.candidates[0] == frozenset({"/usb_cam"}), killed
    assert all("/Signal_generator" not in c for c in killed.candidates), killed

    assert wait_for(lambda: healthy(sink), 30), f"never healthy again: {sink.latest()}"
    fault = injector.begin("offset", "/signal", value=5.0)
    assert wait_for(lambda: (d := sink.latest()) is not None and bool(d.failed), 10)
    wrong = sink.latest()
    injector.end(fault)
    assert wrong is not None and wrong.candidates[0] == frozenset({"/Signal_generator"}), wrong
