"""Awkward but healthy robots on real ROS 1 get the verdicts docs/ros1.md defines and no
alarm their configuration did not ask for: a publisher sending in bursts, a topic whose
only publisher keeps restarting, a node whose XML-RPC API answers in seconds
(``scripts/ros1_robot/awkward_node.py``)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.app import RunOptions
from blackbox.model import Code
from conftest import black_box_running, wait_for
from test_gaps_ros1 import Seen

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from robot import ROS_PYTHON, ThesisRobot, free_port

pytestmark = [pytest.mark.ros1, pytest.mark.slow,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

AWKWARD = Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot" / "awkward_node.py"


class AwkwardRobot(ThesisRobot):
    """A ROS 1 master with awkward nodes of ``awkward_node.py`` instead of the thesis's."""

    def start_awkward(self, role: str, *args: str) -> subprocess.Popen[bytes]:
        name = f"/{role}_node"
        fd = self._log(name)
        proc = subprocess.Popen([ROS_PYTHON, str(AWKWARD), role, *args], env=self.env,
                                stdout=fd, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        os.close(fd)
        self.nodes[name] = proc
        return proc


@pytest.fixture
def master(tmp_path: Path) -> Iterator[AwkwardRobot]:
    r = AwkwardRobot(free_port(), log_dir=tmp_path / "logs")
    try:
        r.start_master()
        yield r
    finally:
        r.stop()


def write_config(path: Path, observers: str) -> Path:
    path.write_text(f"version: 1\nrobot: {{id: awkward}}\nobservers:\n{observers}",
                    encoding="utf-8")
    return path


def healthy(seen: Seen, since: float, count: int) -> bool:
    """Every one of ``count`` observers judged OK in its latest verdict since ``since``."""
    latest = {o.key(): o for o in list(seen.observations) if o.time >= since}
    return len(latest) >= count and all(o.code == Code.GENERAL_OK for o in latest.values())


def latest(seen: Seen) -> list[str]:
    """The latest verdict of each observer and the black box's last events, for a failure."""
    last = {o.key(): o for o in list(seen.observations)}
    return ([f"{o.observer} {o.code}: {o.message}" for o in last.values()]
            + [f"{e.kind}: {e.message}" for e in list(seen.events)[-8:]])


def test_a_publisher_sending_in_bursts_reads_as_its_mean_rate_and_raises_no_alarm(
        master: AwkwardRobot, tmp_path: Path) -> None:
    """100 messages at once every second: an ``hz`` window of at least one whole burst
    cycle (100 periods) reads the mean period, 0.01 s, steadily; no time-out, the node
    alive, and the black box neither behind nor in a gap of the topic."""
    config = write_config(tmp_path / "burst.yaml", """\
  - {type: activated, node: /burst_node, start_up_time: 1.0}
  - type: hz
    topic: /burst
    filter: {type: mean, window_size: 200, deviation: std_deviation}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.01, std_deviation: 0.005}}}
  - {type: timeout, topic: /burst, timeout: 2.0, max_timeouts_in_a_row: 2000}
""")
    master.start_awkward("burst", "--count", "100", "--every", "1.0")
    master.wait_registered(["/burst_node"])
    seen = Seen()
    with black_box_running(RunOptions(config=config, source=f"ros1://127.0.0.1:{master.port}",
                                      live=False, extra_sinks=[seen])):
        began = time.time()
        assert wait_for(lambda: healthy(seen, began + 3.0, 3), 30), latest(seen)
        settled = time.time()
        assert not wait_for(lambda: bool(seen.alarms(settled)), 12.0), seen.alarms(settled)
        periods = [o.values["period"] for o in seen.observations
                   if o.time >= settled and o.observer == "hz"]
        assert periods and all(0.005 <= float(p) <= 0.015 for p in periods), periods  # type: ignore[arg-type]
        # bursts are neither a gap of the topic nor more than the black box can take (a gap
        # of everything, the black box itself starved on a busy machine, may come)
        odd = [e for e in seen.events if e.kind == "ros1_behind"
               or (e.kind == "not_measured" and e.component == "/burst")]
        assert odd == [], [e.message for e in odd]


def test_a_topic_whose_only_publisher_keeps_restarting_is_a_gap_at_each_return(
        master: AwkwardRobot, tmp_path: Path) -> None:
    """The only publisher of /flaky is killed and started again every 3 s. Its silence while
    it is down is the robot's (a 6 s time-out allows it); from its return to its first
    message on the black box's new connection is the black box's, a gap: no alarm, and a
    gap closed at each return."""
    config = write_config(tmp_path / "flaky.yaml", """\
  - {type: timeout, topic: /flaky, timeout: 6.0, max_timeouts_in_a_row: 2000}
""")
    master.start_awkward("steady")
    master.wait_registered(["/steady_node"])
    seen = Seen()
    with black_box_running(RunOptions(config=config, source=f"ros1://127.0.0.1:{master.port}",
                                      live=False, extra_sinks=[seen])):
        began = time.time()
        assert wait_for(lambda: healthy(seen, began + 2.0, 1), 30), latest(seen)
        settled = time.time()
        restarts = 4
        for i in range(restarts):
            time.sleep(3.0)  # the restart cadence is the input under test, not a wait
            killed = time.time()
            os.kill(master.pid("/steady_node"), signal.SIGKILL)
            master.nodes["/steady_node"].wait(timeout=5)
            master.start_awkward("steady")
            # A gap of /flaky from this restart: the new registration or, when the lost
            # connection is noticed first, the reconnection (which of the two depends on
            # timing on a loaded machine; either way not a verdict).
            assert wait_for(lambda k=killed: any(
                e.component == "/flaky" and e.time >= k
                and ("re-registered" in e.message or "reconnect" in e.message)
                for e in seen.gaps()), 15), (i, latest(seen))
        last = time.time()
        assert wait_for(lambda: healthy(seen, last, 1), 15), "not healthy after the restarts"
        assert seen.alarms(settled) == []


def test_a_node_answering_its_api_in_seconds_is_running_while_its_messages_arrive(
        master: AwkwardRobot, tmp_path: Path) -> None:
    """Every slave API call of /slow_api_node takes 1.5 s (the probe waits 0.5 s). Its
    messages keep arriving, so it is running (``ros1_slow_api`` says why), its topic is
    subscribed (``requestTopic`` may take up to ``connect_timeout``) and judged normally.
    Stopped (SIGSTOP), it sends nothing and is reported not running: the rule does not make
    a dead node alive."""
    config = write_config(tmp_path / "slow.yaml", """\
  - {type: activated, node: /slow_api_node, start_up_time: 1.0}
  - type: hz
    topic: /slow
    filter: {type: mean, window_size: 20, deviation: std_deviation}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.1, std_deviation: 0.02}}}
  - {type: timeout, topic: /slow, timeout: 1.0, max_timeouts_in_a_row: 2000}
""")
    master.start_awkward("slow_api", "--delay", "1.5")
    master.wait_registered(["/slow_api_node"])
    seen = Seen()
    with black_box_running(RunOptions(config=config, source=f"ros1://127.0.0.1:{master.port}",
                                      live=False, extra_sinks=[seen])):
        began = time.time()
        assert wait_for(lambda: healthy(seen, began + 3.0, 3), 40), latest(seen)
        settled = time.time()
        assert not wait_for(lambda: bool(seen.alarms(settled)), 12.0), seen.alarms(settled)
        assert any(e.kind == "ros1_slow_api" and e.component == "/slow_api_node"
                   for e in seen.events)
        os.kill(master.pid("/slow_api_node"), signal.SIGSTOP)
        try:
            stopped = time.time()
            assert wait_for(lambda: any(
                o.observer == "activated" and o.faulty and o.time >= stopped
                for o in seen.alarms(stopped)), 10), "a stopped slow node still counts as running"
        finally:
            os.kill(master.pid("/slow_api_node"), signal.SIGCONT)


def test_a_slow_node_the_black_box_does_not_subscribe_to_is_running_while_it_answers_late(
        master: AwkwardRobot, tmp_path: Path) -> None:
    """Only the node's liveness is observed, so no message speaks for it: a patient probe
    (up to 5 s) beside the rounds gets its answers, 1.5 s late, and that keeps it running.
    Stopped, its process says so at once."""
    config = write_config(tmp_path / "slow_alone.yaml", """\
  - {type: activated, node: /slow_api_node, start_up_time: 1.0}
""")
    master.start_awkward("slow_api", "--delay", "1.5")
    master.wait_registered(["/slow_api_node"])
    seen = Seen()
    with black_box_running(RunOptions(config=config, source=f"ros1://127.0.0.1:{master.port}",
                                      live=False, extra_sinks=[seen])):
        began = time.time()
        assert wait_for(lambda: healthy(seen, began + 3.0, 1), 40), latest(seen)
        settled = time.time()
        assert not wait_for(lambda: bool(seen.alarms(settled)), 12.0), seen.alarms(settled)
        assert any(e.kind == "ros1_slow_api" and "late" in e.message for e in seen.events)
        os.kill(master.pid("/slow_api_node"), signal.SIGSTOP)
        try:
            stopped = time.time()
            assert wait_for(lambda: bool(seen.alarms(stopped)), 5), \
                "a stopped slow node still counts as running"
        finally:
            os.kill(master.pid("/slow_api_node"), signal.SIGCONT)
