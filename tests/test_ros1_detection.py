"""End to end on the real thesis robot: each fault kind, injected into the real processes,
is detected by the right observer on the right resource within 2 s."""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.app import RunOptions
from blackbox.model import Resource
from conftest import Collected, black_box_running, wait_for

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from inject import Injector
from robot import ThesisRobot, free_port

pytestmark = [pytest.mark.ros1, pytest.mark.slow,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

# The thesis observers with 10-sample windows, so a changed rate or value shows within 2 s.
CONFIG = """
version: 1
robot: {id: thesis-robot}
observers:
  - {type: activated, node: /audio_capture, start_up_time: 1.0}
  - {type: activated, node: /usb_cam, start_up_time: 1.0}
  - {type: activated, node: /Signal_generator, start_up_time: 1.0}
  - type: hz
    topic: /usb_cam/image_raw
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.0666667, std_deviation: 0.01}}}
  - {type: timeout, topic: /audio, timeout: 1.0}
  - {type: timeout, topic: /usb_cam/image_raw, timeout: 1.0}
  - {type: timeout, topic: /signal, timeout: 1.0}
  - type: scores
    topic: /signal
    field: data
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, score: {value: {type: gauss, mean: 15.0, std_deviation: 0.5}}}
"""


@pytest.fixture
def running(tmp_path: Path) -> Iterator[tuple[ThesisRobot, Collected]]:
    config = tmp_path / "observers.yaml"
    config.write_text(CONFIG)
    robot = ThesisRobot(free_port(), log_dir=tmp_path / "logs").start()
    sink = Collected()
    options = RunOptions(config=config, source=f"ros1://127.0.0.1:{robot.port}", live=False,
                         extra_sinks=[sink])
    try:
        with black_box_running(options):
            yield robot, sink
    finally:
        robot.stop()

CASES = [
    ("kill", "/Signal_generator", {}, "activated", Resource(node="/Signal_generator")),
    ("stall", "/audio", {}, "timeout", Resource(topic="/audio")),
    ("rate", "/usb_cam/image_raw", {"hz": 5.0}, "hz", Resource(topic="/usb_cam/image_raw")),
    ("offset", "/signal", {"value": 5.0}, "scores", Resource(topic="/signal")),
]


def test_each_fault_kind_is_detected_on_its_resource_within_two_seconds(
        running: tuple[ThesisRobot, Collected]) -> None:
    robot, sink = running
    injector = Injector(robot)
    delays: dict[str, float] = {}
    for kind, component, params, observer, resource in CASES:
        settled = time.time()
        assert wait_for(lambda o=observer, r=resource, s=settled: any(
            not x.faulty for x in sink.about(o, r, s)), 20), f"{observer} {resource} never ok"
        fault = injector.begin(kind, component, **params)
        detected = wait_for(lambda o=observer, r=resource, f=fault: any(
            x.faulty for x in sink.about(o, r, f.start)), 5)
        injector.end(fault)
        assert detected, f"{kind} on {component} not detected by {observer}"
        first = next(x for x in sink.about(observer, resource, fault.start) if x.faulty)
        delays[kind] = first.time - fault.start
        if kind == "kill":
            robot.wait_registered([component])
    print("detection delays (s):", {k: round(v, 2) for k, v in delays.items()})
    assert all(d <= 2.0 for d in delays.values()), delays
