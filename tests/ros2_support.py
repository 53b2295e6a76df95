"""Helpers for the ROS 2 tests: per-test domain ids, the rclpy robot, a collecting source."""

from __future__ import annotations

import importlib.util
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from blackbox.events import Event, GraphSnapshot, Interest, MeasurementGap, MessageArrival
from blackbox.model import BlackBoxEvent
from blackbox.sources.ros2 import Ros2Settings, Ros2Source

ROBOT_SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "ros2_robot" / "robot.py"


def _load_robot() -> ModuleType:
    """``scripts/ros2_robot/robot.py`` under a name of its own: the ROS 1 tests import
    ``scripts/ros1_robot/robot.py`` as ``robot``."""
    name = "ros2_thesis_robot"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROBOT_SCRIPT)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


ros2_robot = _load_robot()

try:
    import rclpy  # noqa: F401

    HAVE_RCLPY = True
except ImportError:  # the wheels exist for x86_64 only
    HAVE_RCLPY = False

needs_rclpy = pytest.mark.skipif(not HAVE_RCLPY, reason="needs the ros-rclpy wheels (x86_64)")



class Watched:
    """A started :class:`Ros2Source` whose events a test polls and keeps."""

    def __init__(self, domain: int, interest: Interest,
                 settings: Ros2Settings | None = None) -> None:
        self.source = Ros2Source(domain, settings)
        self.source.start(interest)
        self.events: list[Event] = []

    def pump(self, seconds: float = 0.05) -> list[Event]:
        new = self.source.poll(time.time() + seconds)
        self.events.extend(new)
        return new

    def until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.pump()
            if condition():
                return True
        return condition()

    def arrivals(self, topic: str) -> list[MessageArrival]:
        return [e for e in self.events if isinstance(e, MessageArrival) and e.topic == topic]

    def gaps(self, topic: str) -> list[MeasurementGap]:
        return [e for e in self.events if isinstance(e, MeasurementGap) and e.topic == topic]

    def graphs(self) -> list[GraphSnapshot]:
        return [e for e in self.events if isinstance(e, GraphSnapshot)]

    def reports(self, kind: str) -> list[BlackBoxEvent]:
        return [e for e in self.events if isinstance(e, BlackBoxEvent) and e.kind == kind]

    def close(self) -> None:
        self.source.close()
