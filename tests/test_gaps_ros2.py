"""The black box's own hiccups on the real ROS 2 thesis robot (rclpy, Fast DDS) are
measurement gaps, never alarms or strangers: a node's DDS participant restarting (its
messages are held back until the new participant is known and names its nodes) and the
black box itself stopped for 3 s."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.events import Interest, MeasurementGap
from blackbox.model import Code
from conftest import wait_for
from isolation import fresh_domain
from ros2_support import Watched, needs_rclpy, ros2_robot
from test_gaps_ros1 import Seen

pytestmark = [pytest.mark.ros2, pytest.mark.slow, needs_rclpy]

CAMERA = "/usb_cam/image_raw"
CONFIG = f"""
version: 1
robot: {{id: thesis-robot-ros2}}
observers:
  - {{type: activated, node: /audio_capture, start_up_time: 1.0}}
  - type: hz
    topic: {CAMERA}
    filter: {{type: mean, window_size: 10, deviation: std_deviation}}
    states:
      - {{number: 1, name: ok,
         period: {{value: {{type: gauss, mean: 0.0666667, std_deviation: 0.01}}}}}}
  - type: hz
    topic: /audio
    filter: {{type: mean, window_size: 10, deviation: std_deviation}}
    states:
      - {{number: 1, name: ok, period: {{value: {{type: gauss, mean: 0.03, std_deviation: 0.01}}}}}}
"""


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[tuple[int, object, Path]]:
    domain = fresh_domain()
    config = tmp_path / "observers.yaml"
    config.write_text(CONFIG, encoding="utf-8")
    r = ros2_robot.ThesisRobot2(domain, log_dir=tmp_path / "logs").start(
        ["/usb_cam", "/audio_capture"])
    try:
        yield domain, r, config
    finally:
        r.stop()


def healthy(seen: Seen, since: float, count: int = 3) -> bool:
    latest = {o.key(): o for o in list(seen.observations) if o.time >= since}
    return len(latest) >= count and all(o.code == Code.GENERAL_OK for o in latest.values())


def test_a_restarted_participant_is_named_or_a_gap_never_a_stranger(
        robot: tuple[int, object, Path]) -> None:
    """/usb_cam killed and started again three times: each time a new DDS participant whose
    messages may arrive before discovery has told the source of its writer or before it has
    named its nodes on ``ros_discovery_info`` (that takes from nothing to about 3 s). Such
    messages are held back, never reported under a ``dds:...`` name (which an ``hz`` of the
    whole topic would count, with the restart's silence as one long period), and the time
    they were held back is a closed gap of the camera topic, ended by the node's name."""
    domain, r, _config = robot
    watched = Watched(domain, Interest(topics=frozenset({CAMERA})))
    try:
        assert watched.until(lambda: len(watched.arrivals(CAMERA)) >= 20, 40), \
            "no camera messages"
        for _ in range(3):
            r.kill("/usb_cam")  # type: ignore[attr-defined]
            # silent for a whole second within 10 s (what was sent before the kill may still
            # be on its way on a loaded machine)
            deadline = time.monotonic() + 10
            while True:
                count = len(watched.arrivals(CAMERA))
                if not watched.until(lambda c=count: len(watched.arrivals(CAMERA)) > c, 1.0):
                    break
                assert time.monotonic() < deadline, "the killed camera's messages go on"
            r.start_node("/usb_cam")  # type: ignore[attr-defined]
            assert watched.until(lambda c=count: len(watched.arrivals(CAMERA)) >= c + 20, 30), \
                "the restarted camera never delivered"
        publishers = {a.publisher for a in watched.arrivals(CAMERA)}
        assert publishers == {"/usb_cam"}, publishers
        # Beside the start gap (until the topic's first message, tests/test_ros2_source.py)
        # and CPU starvation on a busy machine (restarted rclpy nodes wait for a core).
        gaps = [e for e in watched.events if isinstance(e, MeasurementGap)
                and not e.reason.startswith("waiting for the first message")
                and "starved" not in e.reason]
        opened = {g.start for g in gaps if g.end is None}
        closed = [g for g in gaps if g.end is not None]
        assert opened == {g.start for g in closed}, "a held-back gap was never closed"
        assert all(g.topic == CAMERA and g.reason.endswith("named: /usb_cam") for g in closed)
        for g in closed:
            assert g.end is not None
            inside = [a for a in watched.arrivals(CAMERA) if g.start < a.time < g.end]
            assert inside == [], f"{len(inside)} messages reported inside {g.reason}"
    finally:
        watched.close()


def test_the_black_box_on_ros2_stopped_for_three_seconds_raises_no_alarm(
        robot: tuple[int, object, Path], tmp_path: Path) -> None:
    """A real ``blackbox run --source ros2:N`` process, SIGSTOPped for 3 s and continued:
    the ROS 2 source's clock watch reports a gap of everything and nothing times out."""
    domain, _r, config = robot
    observations, events = tmp_path / "obs.jsonl", tmp_path / "events.jsonl"
    blackbox = Path(sys.executable).parent / "blackbox"
    proc = subprocess.Popen(
        [str(blackbox), "run", "--source", f"ros2:{domain}", "--config", str(config),
         "--observations", str(observations), "--events", str(events), "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env=ros2_robot.ros2_env(domain))

    def records(path: Path) -> list[dict[str, object]]:
        if not path.exists():
            return []
        text = path.read_text()
        whole = text[:text.rfind("\n") + 1]  # a line still being written is left for later
        return [json.loads(line) for line in whole.splitlines() if line]

    def healthy_since(t: float) -> bool:
        latest: dict[str, dict[str, object]] = {}
        for rec in records(observations):
            if float(rec["time"]) >= t:  # type: ignore[arg-type]
                latest[json.dumps([rec["observer"], rec["resource"]])] = rec
        return len(latest) >= 3 and all(rec["code"] == 0 for rec in latest.values())

    try:
        began = time.time()
        assert wait_for(lambda: healthy_since(began + 2.0), 40), "never healthy"
        settled = time.time()
        proc.send_signal(signal.SIGSTOP)
        stopped = time.time()
        assert not wait_for(lambda: proc.poll() is not None, 3.0)  # 3 s stopped
        proc.send_signal(signal.SIGCONT)
        assert wait_for(lambda: any(
            rec["kind"] == "measured_again" and "did not run" in str(rec["message"])
            and float(rec["time"]) >= stopped for rec in records(events)), 10), "no pause gap"  # type: ignore[arg-type]
        cont = time.time()
        assert wait_for(lambda: healthy_since(cont + 2.0), 20), "not healthy after the pause"
        alarms = [rec for rec in records(observations)
                  if float(rec["time"]) >= settled and rec["code"] not in (0, -3)]  # type: ignore[arg-type]
        assert alarms == [], json.dumps(alarms)[:2000]
    finally:
        proc.send_signal(signal.SIGCONT)
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def test_a_late_dds_thread_is_waited_for_not_handed_out_as_silence(
        robot: tuple[int, object, Path]) -> None:
    """On a busy machine the source's DDS thread may run later than the pipeline's, which
    polls at its evaluation instants. What the robot sent before such an instant but was
    not yet taken used to be missing at the evaluation (silence: a provisional period, a
    time-out) and then crowded in after it: the black box's own lag read as a wrong rate.
    Here every pass of the DDS thread over its readers starts 0.45 s late; at each horizon
    the last /audio message handed out (33 Hz) must still be a period or so old, because
    ``poll`` waits for a pass that began at its horizon."""
    domain, _r, _config = robot
    watched = Watched(domain, Interest(topics=frozenset({"/audio"})))
    source = watched.source
    take_all = source._take_all

    def late_take_all() -> None:
        time.sleep(0.45)  # the DDS thread scheduled late: the input, not a wait
        take_all()

    try:
        assert watched.until(lambda: len(watched.arrivals("/audio")) >= 30, 40), \
            "no /audio messages"
        source._take_all = late_take_all  # type: ignore[method-assign]
        watched.pump(1.0)
        silences: list[float] = []
        gapped = 0
        last = max(a.time for a in watched.arrivals("/audio"))
        for _ in range(20):
            horizon = time.time() + 0.5
            new = source.poll(horizon)
            watched.events.extend(new)
            if any(isinstance(e, MeasurementGap) and e.everything for e in new):
                gapped += 1
                continue
            last = max([last] + [e.time for e in new if getattr(e, "topic", None) == "/audio"
                                 and not isinstance(e, MeasurementGap)])
            silences.append(horizon - last)
        assert gapped <= 2, f"{gapped} of 20 polls were gaps: the wait is too short"
        long = [round(s, 3) for s in silences if s > 0.3]
        assert len(long) <= 1, f"silences at the horizons over 0.3 s: {long}"
    finally:
        source._take_all = take_all  # type: ignore[method-assign]
        source.close()
