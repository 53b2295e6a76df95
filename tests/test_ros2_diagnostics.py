"""``--publish-diagnostics``: the verdicts reach a real rclpy subscriber of ``/diagnostics``
as ``diagnostic_msgs/DiagnosticArray``, levels mapped from the UCMS health status."""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from blackbox.app import RunOptions
from blackbox.health.status import Health
from blackbox.output.diagnostics import LEVEL_OF_HEALTH
from conftest import black_box_running
from isolation import fresh_domain
from ros2_support import needs_rclpy, ros2_robot

CONFIG = """
version: 1
robot: {id: r2}
observers:
  - {type: activated, node: /audio_capture, start_up_time: 1.0, every: 0.25}
  - {type: timeout, topic: /audio, timeout: 1.0}
"""


def test_levels_follow_the_ucms_health_status() -> None:
    assert LEVEL_OF_HEALTH == {Health.OPERATIONAL: 0, Health.DEGRADED: 1,
                               Health.NOT_OPERATIONAL: 2, Health.UNKNOWN: 3}


def _spin_until(client: Any, condition: Callable[[], bool], timeout: float) -> bool:
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=client.context)
    executor.add_node(client.node)
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline and not condition():
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.remove_node(client.node)
    return condition()


@needs_rclpy
@pytest.mark.ros2
def test_a_killed_node_shows_ok_then_error_on_diagnostics(tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray

    domain = fresh_domain()
    config = tmp_path / "observers.yaml"
    config.write_text(CONFIG)
    robot = ros2_robot.ThesisRobot2(domain, log_dir=tmp_path / "logs").start(["/audio_capture"])
    client = ros2_robot.ParameterClient(domain)
    levels: list[tuple[float, int, str]] = []

    def heard(msg: DiagnosticArray) -> None:
        levels.extend((time.time(), int.from_bytes(s.level, "little")
                       if isinstance(s.level, bytes) else int(s.level), s.message)
                      for s in msg.status if s.name == "blackbox/r2/audio_capture")

    client.node.create_subscription(DiagnosticArray, "/diagnostics", heard, 10)
    try:
        # off by default: no /diagnostics publisher in the robot's graph
        with black_box_running(RunOptions(config=config, source=f"ros2:{domain}",
                                          live=False)):
            _spin_until(client, lambda: False, 2.0)
            assert client.node.count_publishers("/diagnostics") == 0
        options = RunOptions(config=config, source=f"ros2:{domain}", live=False,
                             publish_diagnostics=True)
        with black_box_running(options):
            assert _spin_until(client, lambda: any(lv == 0 for _, lv, _ in levels), 20), levels
            assert client.node.count_publishers("/diagnostics") == 1  # the check above can fail
            killed = time.time()
            robot.kill("/audio_capture", signal.SIGKILL)
            assert _spin_until(client, lambda: any(
                t > killed and lv == 2 for t, lv, _ in levels), 10), levels[-3:]
            error = next(m for t, lv, m in levels if t > killed and lv == 2)
            assert error.startswith("not operational") and "activated" in error
    finally:
        client.close()
        robot.stop()
