"""`blackbox learn` on real ROS 1 processes: the thesis robot plus a laser driver and a node
using its scans, parts no hand-written thesis observer covers. A configuration learned from
a short healthy run detects a killed node, a stopped node, a slowed topic and a driver
publishing wrong values at the right rate; a node killed while learning is reported."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest

from blackbox.app import RunOptions
from blackbox.learn import learn_from, render_config, render_model
from blackbox.model import Diagnosis, Observation, Resource
from blackbox.observe.build import load_config
from blackbox.sinks import SinkBase
from blackbox.sources import open_source
from conftest import black_box_running, wait_for

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from inject import Injector
from robot import HERE as ROBOT_DIR
from robot import ROS_PYTHON, ThesisRobot, free_port

pytestmark = [pytest.mark.ros1, pytest.mark.slow,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

LEARN_SECONDS = 25.0


class Collect(SinkBase):
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.observations: list[Observation] = []
        self.diagnoses: list[Diagnosis] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self.lock:
            self.observations.extend(observations)

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self.lock:
            self.diagnoses.append(diagnosis)

    def latest(self, observer: str, resource: Resource) -> Observation | None:
        with self.lock:
            return next((o for o in reversed(self.observations)
                         if o.observer == observer and o.resource == resource), None)

    def faulty_since(self, t: float, observer: str, resource: Resource) -> bool:
        with self.lock:
            return any(o.faulty and o.time >= t and o.observer == observer
                       and o.resource == resource for o in self.observations)

    def candidates_since(self, t: float) -> list[frozenset[str]]:
        with self.lock:
            return [c for d in self.diagnoses if d.time >= t for c in d.candidates]


def start_laser_nodes(robot: ThesisRobot, log_dir: Path) -> None:
    for name, role in (("/laser_driver", "laser"), ("/obstacle_monitor", "monitor")):
        log = open(log_dir / f"{role}.log", "wb")  # noqa: SIM115 (closed with the process)
        robot.nodes[name] = subprocess.Popen(
            [ROS_PYTHON, str(ROBOT_DIR / "laser_nodes.py"), role], env=robot.env,
            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            start_new_session=True)
        log.close()
    robot.wait_registered(["/laser_driver", "/obstacle_monitor"])


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[ThesisRobot]:
    (tmp_path / "logs").mkdir()
    robot = ThesisRobot(free_port(), log_dir=tmp_path / "logs").start()
    try:
        start_laser_nodes(robot, tmp_path / "logs")
        yield robot
    finally:
        robot.stop()


def learn(robot: ThesisRobot, seconds: float, out: Path,
          during: Callable[[float], None] | None = None) -> Path:
    spec = f"ros1://127.0.0.1:{robot.port}"
    learned = learn_from(lambda: open_source(spec), seconds,
                         progress=(lambda done, rec: during(done)) if during else None)
    path = out / "robot.yaml"
    path.write_text(render_config(learned, "ros1-robot", "robot.model.yaml", "test"))
    (out / "robot.model.yaml").write_text(render_model(learned, "test"))
    return path


def test_learned_configuration_detects_faults_on_real_nodes(robot: ThesisRobot,
                                                            tmp_path: Path) -> None:
    config = learn(robot, LEARN_SECONDS, tmp_path)
    kinds = {(e["type"].str(), (e.get("topic") or e["node"]).str())
             for e in load_config(config).observers}
    assert {("fields", "/scan"), ("fields", "/min_distance"), ("timestamp", "/scan"),
            ("hz", "/scan"), ("activated", "/laser_driver"),
            ("resources", "/obstacle_monitor")} <= kinds, kinds
    sink = Collect()
    injector = Injector(robot)
    options = RunOptions(config=config, source=f"ros1://127.0.0.1:{robot.port}", live=False,
                         extra_sinks=[sink])
    scan_values = Resource(topic="/scan")
    with black_box_running(options):
        assert wait_for(lambda: (o := sink.latest("fields", scan_values)) is not None
                        and not o.faulty, 20), sink.latest("fields", scan_values)

        fault = injector.begin("kill", "/usb_cam")
        assert wait_for(lambda: sink.faulty_since(fault.start, "activated",
                                                  Resource(node="/usb_cam")), 5)
        injector.end(fault)
        robot.wait_registered(["/usb_cam"])

        fault = injector.begin("stall", "/audio")
        assert wait_for(lambda: sink.faulty_since(fault.start, "timeout",
                                                  Resource(topic="/audio")), 5)
        injector.end(fault)

        fault = injector.begin("rate", "/signal", hz=5.0)
        assert wait_for(lambda: sink.faulty_since(fault.start, "hz",
                                                  Resource(topic="/signal")), 5)
        injector.end(fault)

        assert wait_for(lambda: not sink.latest("fields", scan_values).faulty, 10)  # type: ignore[union-attr]
        injector_time = time.time()
        robot.set_param("/laser_driver/offset", 0.5)
        assert wait_for(lambda: sink.faulty_since(injector_time, "fields", scan_values), 5)
        assert wait_for(lambda: any("/laser_driver" in c
                                    for c in sink.candidates_since(injector_time)), 5), \
            sink.candidates_since(injector_time)
        robot.set_param("/laser_driver/offset", 0.0)


def test_a_node_killed_while_learning_is_reported(robot: ThesisRobot, tmp_path: Path) -> None:
    killed: list[bool] = []

    def kill_audio_once(done: float) -> None:
        if done >= 4.0 and not killed:
            os.kill(robot.pid("/audio_capture"), signal.SIGKILL)
            killed.append(True)

    config = learn(robot, 12.0, tmp_path, during=kill_audio_once)
    text = " ".join(line.strip().lstrip("#").strip()
                    for line in config.read_text().splitlines())
    assert killed and "node /audio_capture: not running from" in text
    assert "to the end of the run" in text
    load_config(config)
