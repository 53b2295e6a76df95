"""The two real diffdrive robots (issue 22) as modules of their own names, and the ROS 2
robot started until it publishes.

``scripts/ros1_robot/diffdrive_robot.py`` and ``scripts/ros2_robot/diffdrive_robot.py`` share a
file name, and each has a sibling ``robot.py``; loaded by path under distinct names, both live
in one test process beside the ROS 1 tests' ``robot`` module.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"


def load_script(path: Path, name: str) -> ModuleType:
    """The module at ``path``, imported once as ``name``."""
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


ros1_diffdrive = load_script(SCRIPTS / "ros1_robot" / "diffdrive_robot.py", "ros1_diffdrive_robot")
ros2_diffdrive = load_script(SCRIPTS / "ros2_robot" / "diffdrive_robot.py", "ros2_diffdrive_robot")
motion_model = load_script(SCRIPTS / "robots" / "diffdrive_motion.py", "diffdrive_motion")


@contextmanager
def ros2_diffdrive_publishing(domain: int, *, seed: int, log_dir: Path, epoch: float,
                              faults: tuple[int, float, float] = (0, 0.0, 0.0),
                              transports: str | None = None,
                              within: float = 30.0) -> Iterator[Any]:
    """The real ROS 2 diffdrive robot (a ``DiffdriveRobot2``), started and yielded once every
    one of its topics has published, stopped on exit.

    Learning and observing watch a running robot: rclpy nodes take seconds to start here,
    and a learner started before them sees only part of the graph. Raises AssertionError
    naming the silent topics if they do not all publish ``within`` seconds of the start.
    """
    from blackbox.events import Interest
    from ros2_support import Watched

    robot = ros2_diffdrive.DiffdriveRobot2(domain, seed=seed, log_dir=log_dir, epoch=epoch,
                                           faults=faults, transports=transports)
    try:
        robot.start()
        topics = frozenset(ros2_diffdrive.TOPICS)
        watched = Watched(domain, Interest(topics))
        try:
            if not watched.until(lambda: all(watched.arrivals(t) for t in topics), within):
                silent = sorted(t for t in topics if not watched.arrivals(t))
                raise AssertionError(f"every topic of the ROS 2 robot publishing within "
                                     f"{within:g} s of its start; silent: {silent}")
        finally:
            watched.close()
        yield robot
    finally:
        robot.stop()
