"""End to end on the thesis robot rebuilt as rclpy nodes: the black box, built from the same
observer configuration as on ROS 1, catches a slowed publisher (hz), a wrong value (scores)
and a killed node (activated) on the right resource."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.app import RunOptions
from blackbox.model import Resource
from conftest import Collected, black_box_running, wait_for
from isolation import fresh_domain
from ros2_support import needs_rclpy, ros2_robot

pytestmark = [pytest.mark.ros2, needs_rclpy]

CONFIG = """
version: 1
robot: {id: thesis-robot-ros2}
observers:
  - {type: activated, node: /audio_capture, start_up_time: 1.0, every: 0.25}
  - type: hz
    topic: /usb_cam/image_raw
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.0666667, std_deviation: 0.01}}}
  - type: scores
    topic: /signal
    field: data
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, score: {value: {type: gauss, mean: 15.0, std_deviation: 0.5}}}
"""


@pytest.fixture
def running(tmp_path: Path) -> Iterator[tuple[object, object, Collected]]:
    domain = fresh_domain()
    config = tmp_path / "observers.yaml"
    config.write_text(CONFIG)
    robot = ros2_robot.ThesisRobot2(domain, log_dir=tmp_path / "logs").start()
    params = ros2_robot.ParameterClient(domain)
    sink = Collected()
    options = RunOptions(config=config, source=f"ros2:{domain}", live=False,
                         extra_sinks=[sink])
    try:
        with black_box_running(options):
            yield robot, params, sink
    finally:
        params.close()
        robot.stop()


def _ok_then_faulty(sink: Collected, observer: str, resource: Resource, inject,
                    timeout: float = 5.0) -> float:
    settled = time.time()
    assert wait_for(lambda: any(not x.faulty for x in sink.about(observer, resource, settled)),
                    25), f"{observer} {resource.label()} never ok"
    start = time.time()
    inject()
    assert wait_for(lambda: any(x.faulty for x in sink.about(observer, resource, start)),
                    timeout), f"{observer} did not catch the fault on {resource.label()}"
    first = next(x for x in sink.about(observer, resource, start) if x.faulty)
    return first.time - start


def test_slowed_publisher_wrong_value_and_killed_node_are_caught(running) -> None:
    robot, params, sink = running
    delays = {
        "rate": _ok_then_faulty(sink, "hz", Resource(topic="/usb_cam/image_raw"),
                                lambda: params.set("/usb_cam", rate=5.0)),
        "value": _ok_then_faulty(sink, "scores", Resource(topic="/signal"),
                                 lambda: params.set("/Signal_generator", offset=5.0)),
        "kill": _ok_then_faulty(sink, "activated", Resource(node="/audio_capture"),
                                lambda: robot.kill("/audio_capture", signal.SIGKILL)),
    }
    print("detection delays (s):", {k: round(v, 2) for k, v in delays.items()})
    assert delays["kill"] <= 1.0
