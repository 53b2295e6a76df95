"""One real ROS 2 diffdrive robot and one configuration learned from it, shared by the tests
that learn on it (a pytest plugin, registered in conftest.py).

``test_learn_real_faults.py`` (an odometry offset from the robot's own fault schedule) and
``test_learn_real_imu.py``'s ROS 2 case (an IMU yaw offset set through a parameter) both
learned 90 s of the same robot with the same motion: 2 x 100-145 s of one worker and two
robots' CPU for one question each. Both now take :func:`learned_ros2_diffdrive`: the robot
started once with the faults test's schedule, learned once, and each test runs its own black
box against it in its own time window (the IMU test waits out the scheduled odometry offset
when it cannot finish before it). The tests carry the xdist group :data:`GROUP`, so one
worker runs them one after the other; the robot is stopped after the last of them in a row
(``pytest_runtest_teardown``), not at the end of the worker's session, where it would burn
CPU under every later test.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from blackbox.learn import learn_from, render_config, render_model
from blackbox.sources import open_source
from diffdrive_support import SCRIPTS, load_script, ros2_diffdrive_publishing
from isolation import fresh_domain

faults_model = load_script(SCRIPTS / "robots" / "diffdrive_faults.py", "diffdrive_faults")

FIXTURE = "learned_ros2_diffdrive"
GROUP = "learned_ros2_diffdrive"
"""The xdist group of every test taking the fixture: one worker, one robot."""

MOTION_SEED = 5
"""The motion script of the real-middleware tests: learning from motion second ~10 on sees
the robot go straight, stand, turn, go straight, stand and turn, with a turn in the held-out
last 30 %, and is followed by more than 30 s of driving without standing still (standing
still is unjudged when learning saw less than 20 s of it)."""
LEAD = 5.0
"""The robot's motion starts this many seconds into its script."""
LEARN_SECONDS = 90.0
"""With 60 s (a window starting 30 s later), one ROS 1 run of nine learned no relation of
the IMU and three learned only one (the loaded rospy IMU comes in bursts); 90 s learned all
five relations in six of six runs."""
FAULT_SEED = 204
"""Its schedule's only fault in the first 25 s: an offset of 0.132 m/s (8.8 times the
odometry's noise) on ``/odom/twist`` ``twist.linear.x``, 7.7 s after the schedule starts."""
SCHEDULE_START = 143.0
"""Motion second the schedule starts at: the offset falls at 150.7-159.8 s, while the robot
goes straight (148.8-174.4 s for motion seed 5), and leaves the robot 37 s to start before
learning (5 + 37 + 90 + 10 s of settling = 142 s)."""
SCHEDULE_LENGTH = 25.0
START_WITHIN = 90.0
"""Seconds the robot's topics may take to publish (ROS 2 test robots get 90 s: 30 s was
exceeded on a loaded machine). The odometry test needs them within 37 s (SCHEDULE_START)
and says so if they came later; the IMU test does not."""


@dataclass(frozen=True)
class LearnedRobot:
    """The running robot, where its learned configuration is, and when learning ran."""

    robot: Any
    """The ``DiffdriveRobot2`` (scripts/ros2_robot/diffdrive_robot.py, loaded by path)."""
    config: Path
    learn_start: float
    learn_end: float

    @property
    def source(self) -> str:
        return f"ros2:{self.robot.domain_id}"

    @property
    def epoch(self) -> float:
        return float(self.robot.epoch)

    def scheduled_fault(self) -> Any:
        """The schedule's one fault (a ``ScheduledFault``; motion seconds)."""
        (fault,) = faults_model.schedule(FAULT_SEED, SCHEDULE_START, SCHEDULE_LENGTH)
        return fault


def learn(source: str, out: Path) -> Path:
    """``blackbox learn``'s own code on ``source`` for LEARN_SECONDS; the configuration."""
    learned = learn_from(lambda: open_source(source), LEARN_SECONDS)
    config = out / "robot.yaml"
    config.write_text(render_config(learned, "robot", "robot.model.yaml", "test"),
                      encoding="utf-8")
    (out / "robot.model.yaml").write_text(render_model(learned, "test"), encoding="utf-8")
    return config


class _Shared:
    """The robot and its learned configuration while consecutive tests use them."""

    def __init__(self) -> None:
        self.stack: ExitStack | None = None
        self.value: LearnedRobot | None = None

    def get(self, out: Path) -> LearnedRobot:
        """The running robot; started and learned in ``out`` if it is not running."""
        if self.value is None:
            stack = ExitStack()
            try:
                robot = stack.enter_context(ros2_diffdrive_publishing(
                    fresh_domain(), seed=MOTION_SEED, log_dir=out / "logs",
                    epoch=time.time() - LEAD,
                    faults=(FAULT_SEED, SCHEDULE_START, SCHEDULE_LENGTH),
                    within=START_WITHIN))
                learn_start = time.time()
                config = learn(f"ros2:{robot.domain_id}", out)
                self.value = LearnedRobot(robot, config, learn_start, time.time())
            except BaseException:
                stack.close()
                raise
            self.stack = stack
        return self.value

    def close(self) -> None:
        if self.stack is not None:
            self.stack.close()
        self.stack, self.value = None, None


_shared = _Shared()


@pytest.fixture
def learned_ros2_diffdrive(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LearnedRobot]:
    """The shared robot, started and learned by the first test that asks for it."""
    yield _shared.get(tmp_path_factory.mktemp("learned-ros2-diffdrive"))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The tests that use the robot run in a row, from where the first of them was
    collected (under xdist their group does the same), so it is learned once."""
    users = [item for item in items if FIXTURE in getattr(item, "fixturenames", ())]
    if len(users) < 2:
        return
    chosen = {id(item) for item in users}
    at = items.index(users[0])
    rest = [item for item in items if id(item) not in chosen]
    items[:] = [*rest[:at], *users, *rest[at:]]


def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> None:
    """Stop the robot after the last of a row of tests that use it."""
    if FIXTURE in getattr(item, "fixturenames", ()) and (
            nextitem is None or FIXTURE not in getattr(nextitem, "fixturenames", ())):
        _shared.close()


def pytest_sessionfinish() -> None:
    _shared.close()
