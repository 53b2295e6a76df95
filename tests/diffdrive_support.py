"""The two real diffdrive robots (issue 22) as modules of their own names.

``scripts/ros1_robot/diffdrive_robot.py`` and ``scripts/ros2_robot/diffdrive_robot.py`` share a
file name, and each has a sibling ``robot.py``; loaded by path under distinct names, both live
in one test process beside the ROS 1 tests' ``robot`` module.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

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
