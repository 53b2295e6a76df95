"""The black box's own hiccups on the real ROS 1 thesis robot are measurement gaps, never
alarms: a counters/subscription switch when the only on-robot subscriber dies, the black
box itself stopped for 3 s, its wall clock stepped, the master restarted. Each test
asserts a gap event and no faulty verdict the robot did not earn."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from blackbox.app import RunOptions, build
from blackbox.events import Interest, MeasurementGap, MessageArrival
from blackbox.model import BlackBoxEvent, Code, Observation
from blackbox.sinks import SinkBase
from blackbox.sources.ros1.source import Ros1Settings, Ros1Source
from conftest import black_box_running, wait_for
from ros1_watch import Watch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from robot import ThesisRobot, free_port

pytestmark = [pytest.mark.ros1, pytest.mark.slow,
              pytest.mark.skipif(shutil.which("roscore") is None, reason="needs Debian's ROS 1")]

THESIS = Path(__file__).resolve().parent.parent / "src" / "blackbox" / "configs" / "thesis.yaml"
COUNTED = ("/usb_cam/image_raw", "/audio")
"""Topics whose only on-robot subscriber is /Signal_generator: their rates come from the
publishers' counters while it lives, from the black box's own subscription otherwise."""


class Seen(SinkBase):
    """Observations and events of a black box running in a thread of the test."""

    def __init__(self) -> None:
        self.observations: list[Observation] = []
        self.events: list[BlackBoxEvent] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self.observations.extend(observations)

    def on_event(self, event: BlackBoxEvent) -> None:
        self.events.append(event)

    def alarms(self, since: float, topics: Sequence[str] = ()) -> list[Observation]:
        """Faulty verdicts (not ``NOT_AVAILABLE``) since ``since``, on ``topics`` if given."""
        return [o for o in list(self.observations)
                if o.time >= since and o.faulty and o.code != Code.NOT_AVAILABLE
                and (not topics or o.resource.topic in topics)]

    def gaps(self, kind: str = "measured_again") -> list[BlackBoxEvent]:
        return [e for e in list(self.events) if e.kind == kind]

    def ok(self, since: float) -> bool:
        """Every observer judged the robot healthy at least once since ``since`` and none
        faulty in its latest verdict."""
        latest: dict[tuple[str, object], Observation] = {}
        for o in list(self.observations):
            if o.time >= since:
                latest[o.key()] = o
        return len(latest) >= 10 and all(o.code == Code.GENERAL_OK for o in latest.values())


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[ThesisRobot]:
    r = ThesisRobot(free_port(), log_dir=tmp_path / "logs")
    try:
        yield r.start()
    finally:
        r.stop()


def settled(seen: Seen) -> float:
    start = time.time()
    assert wait_for(lambda: seen.ok(start + 3.0), 40), \
        "the thesis robot never showed healthy on every observer"
    return time.time()


def test_killing_the_only_subscriber_of_counted_topics_is_a_gap_not_a_wrong_rate(
        robot: ThesisRobot) -> None:
    seen = Seen()
    options = RunOptions(config=THESIS, source=f"ros1://127.0.0.1:{robot.port}", live=False,
                         extra_sinks=[seen])
    with black_box_running(options):
        start = settled(seen)
        for _ in range(2):
            os.kill(robot.pid("/Signal_generator"), signal.SIGKILL)
            killed = time.time()
            assert wait_for(lambda k=killed: {e.component for e in seen.gaps()
                                              if e.time >= k} >= set(COUNTED), 15), \
                "no gap closed on both counted topics after the kill"
            robot.nodes["/Signal_generator"].wait(timeout=5)
            robot.start_node("/Signal_generator")
            robot.wait_registered(["/Signal_generator"])
            back = time.time()
            assert wait_for(lambda b=back: {e.component for e in seen.gaps()
                                            if e.time >= b} >= set(COUNTED), 15), \
                "no gap on both counted topics when the subscriber came back"
            assert wait_for(lambda b=back: seen.ok(b + 3.0), 20)
        assert seen.alarms(start, COUNTED) == []
        closed = [e.message for e in seen.gaps() if e.component == "/audio"]
        assert any("not measured from" in m and "counters to a subscription" in m
                   for m in closed), closed


def test_the_master_restarting_is_a_graph_gap_and_no_alarm(robot: ThesisRobot) -> None:
    seen = Seen()
    options = RunOptions(config=THESIS, source=f"ros1://127.0.0.1:{robot.port}", live=False,
                         extra_sinks=[seen])
    with black_box_running(options):
        start = settled(seen)
        robot.stop_master()
        assert wait_for(lambda: any("the robot's graph" in e.message
                                    for e in seen.gaps("not_measured")), 10), "no graph gap"
        robot.start_master()
        assert wait_for(lambda: any("the robot's graph: not measured from" in e.message
                                    for e in seen.gaps()), 20), "the graph gap never closed"
        settled_again = time.time()
        assert wait_for(lambda: seen.ok(settled_again), 20)
        assert seen.alarms(start) == []


def test_a_wall_clock_step_either_way_is_a_gap_of_everything_and_no_alarm(
        robot: ThesisRobot) -> None:
    """NTP stepping the clock, faked at the source boundary: the ROS 1 source's
    ``clock_offset`` shifts every time it reads or stamps (kernel stamps included), as a
    stepped ``CLOCK_REALTIME`` would (a time namespace cannot step it)."""
    seen = Seen()
    box = build(RunOptions(config=THESIS, source=f"ros1://127.0.0.1:{robot.port}",
                           live=False, extra_sinks=[seen]))
    source = box.pipeline.source
    stop = threading.Event()
    thread = threading.Thread(target=box.run, args=(stop,), daemon=True)
    thread.start()
    try:
        start = settled(seen)
        for step in (30.0, -60.0):
            before = len(seen.gaps())
            source.clock_offset += step  # type: ignore[attr-defined]
            # other gaps may come meanwhile (a publisher starved by a busy machine)
            assert wait_for(lambda b=before: any(
                "stepped" in g.message for g in seen.gaps()[b:]), 10), f"no gap for {step}"
            [gap] = [g for g in seen.gaps()[before:] if "stepped" in g.message]
            assert gap.component == "blackbox"
            now = source.now()
            assert wait_for(lambda n=now: seen.ok(n + 2.0), 20), f"not healthy after {step}"
        assert seen.alarms(start) == []
    finally:
        stop.set()
        thread.join(timeout=5)


def test_the_black_box_stopped_for_three_seconds_raises_no_alarm(
        robot: ThesisRobot, tmp_path: Path) -> None:
    """A real ``blackbox run`` process, SIGSTOPped for 3 s and continued."""
    observations, events = tmp_path / "obs.jsonl", tmp_path / "events.jsonl"
    blackbox = Path(sys.executable).parent / "blackbox"
    proc = subprocess.Popen(
        [str(blackbox), "run", "--source", f"ros1://127.0.0.1:{robot.port}", "--config",
         str(THESIS), "--observations", str(observations), "--events", str(events),
         "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    def records(path: Path) -> list[dict[str, object]]:
        if not path.exists():
            return []
        text = path.read_text()
        whole = text[:text.rfind("\n") + 1]  # a line still being written is left for later
        return [json.loads(line) for line in whole.splitlines() if line]

    def healthy_since(t: float) -> bool:
        latest: dict[str, dict[str, object]] = {}
        for r in records(observations):
            if float(r["time"]) >= t:  # type: ignore[arg-type]
                latest[json.dumps([r["observer"], r["resource"]])] = r
        return len(latest) >= 10 and all(r["code"] == 0 for r in latest.values())

    try:
        began = time.time()
        assert wait_for(lambda: healthy_since(began + 3.0), 40), "never healthy"
        settled_at = time.time()
        for _ in range(2):
            proc.send_signal(signal.SIGSTOP)
            stopped = time.time()
            assert not wait_for(lambda: proc.poll() is not None, 3.0)  # 3 s stopped
            proc.send_signal(signal.SIGCONT)
            assert wait_for(lambda s=stopped: any(
                r["kind"] == "measured_again" and "did not run" in str(r["message"])
                and float(r["time"]) >= s for r in records(events)), 10), "no pause gap"  # type: ignore[arg-type]
            cont = time.time()
            assert wait_for(lambda c=cont: healthy_since(c + 2.0), 20), "not healthy after"
        alarms = [r for r in records(observations)
                  if float(r["time"]) >= settled_at and r["code"] not in (0, -3)]  # type: ignore[arg-type]
        assert alarms == []
    finally:
        proc.send_signal(signal.SIGCONT)
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def test_a_lost_connection_to_a_live_publisher_is_a_gap_until_it_reconnects(
        robot: ThesisRobot) -> None:
    """The black box's own TCPROS connections break while the publishers live on: the
    reader process holding the camera and audio connections (``readers=1``, subscriptions
    only) is killed. Each topic is a gap from the round before the loss until the first
    message on its new connection, and nothing times out or reads a wrong rate."""
    seen = Seen()
    box = build(RunOptions(config=THESIS, live=False, extra_sinks=[seen],
                           source=f"ros1://127.0.0.1:{robot.port}?readers=1&counters=0"))
    source = box.pipeline.source
    stop = threading.Event()
    thread = threading.Thread(target=box.run, args=(stop,), daemon=True)
    thread.start()
    try:
        start = settled(seen)
        processes = source.reader_processes  # type: ignore[attr-defined]
        assert processes is not None
        for _ in range(2):
            before = time.time()
            (pid,) = processes.pids()
            os.kill(pid, signal.SIGKILL)
            assert wait_for(lambda b=before: {e.component for e in seen.gaps()
                                              if e.time >= b
                                              and "reconnecting" in e.message} >= set(COUNTED),
                            15), "no reconnection gap closed on both topics"
            assert wait_for(lambda p=pid: processes.pids() not in ([], [p]), 10)
            back = time.time()
            assert wait_for(lambda b=back: seen.ok(b + 2.0), 20), "not healthy after"
        assert seen.alarms(start) == []
    finally:
        stop.set()
        thread.join(timeout=5)


def test_a_stalled_counted_topic_leaves_the_other_counted_topics_rate_alone(
        robot: ThesisRobot) -> None:
    """SIGSTOP of the camera node: its probe times out every round, so rounds wait up to
    0.5 s for it, then stop waiting when it continues. The audio topic's rate, counted in
    the same rounds, must read as ever: each round's counts continue where the previous
    round's ended instead of piling up on them (the hz false alarms on /audio during camera
    stalls in the real 10 x 300 s campaign)."""
    seen = Seen()
    options = RunOptions(config=THESIS, source=f"ros1://127.0.0.1:{robot.port}", live=False,
                         extra_sinks=[seen])
    with black_box_running(options):
        start = settled(seen)
        for _ in range(3):
            os.kill(robot.pid("/usb_cam"), signal.SIGSTOP)
            stopped = time.time()
            try:
                assert wait_for(lambda s=stopped: any(
                    o.resource.topic == "/usb_cam/image_raw" or o.resource.node == "/usb_cam"
                    for o in seen.alarms(s)), 10), "the stall was not seen"
                time.sleep(3.0)  # the stall's length is the input, not a wait
            finally:
                os.kill(robot.pid("/usb_cam"), signal.SIGCONT)
            back = time.time()
            assert wait_for(lambda b=back: seen.ok(b + 2.0), 30), "not healthy after the stall"
        assert seen.alarms(start, ["/audio", "/signal"]) == []


def audio(watch: Watch) -> list[float]:
    return [e.time for e in watch.events if isinstance(e, MessageArrival) and e.topic == "/audio"]


def test_a_slow_round_of_counts_is_waited_for_not_handed_out_as_silence(
        robot: ThesisRobot) -> None:
    """The first round after the camera node is stopped waits the whole probe time-out for
    it before the audio publisher's counts are queued. ``poll`` must not hand out its
    horizon before those counts: the uncounted stretch was silence of /audio at the
    evaluation, then a hole in its arrivals (a long period, a wrong rate: the remaining
    false alarms of the real campaign during stalls). A probe time-out of 1 s makes the slow
    round long; at every 1 s horizon, as the pipeline polls, the last /audio arrival handed
    out (33 Hz, counted) must be recent."""
    source = Ros1Source(f"http://127.0.0.1:{robot.port}", Ros1Settings(probe_timeout=1.0))
    source.start(Interest(topics=frozenset({"/audio", "/usb_cam/image_raw"})))
    watch = Watch(source)
    try:
        assert watch.until(lambda: ("/audio", "/audio_capture") in source.counted
                           and len(audio(watch)) > 100, 40), \
            "/audio never counted"
        silences: list[float] = []
        for _ in range(6):
            os.kill(robot.pid("/usb_cam"), signal.SIGSTOP)
            try:
                for _ in range(2):  # polls while stopped: the input, not a wait
                    horizon = time.time() + 1.0
                    watch.events.extend(source.poll(horizon))
                    heard = audio(watch)
                    if not any(isinstance(e, MeasurementGap) and e.topic in (None, "/audio")
                               and e.time >= horizon - 1.0 for e in watch.events):
                        silences.append(horizon - max(heard))
            finally:
                os.kill(robot.pid("/usb_cam"), signal.SIGCONT)
            assert watch.until(lambda: ("/usb_cam/image_raw", "/usb_cam") in source.counted,
                               20), "the camera never counted again"
        # Handed out before the slow round, /audio would be silent for the probe time-out
        # (1 s) and more; a round of counts itself spaces arrivals by up to about half a
        # second (0.518 s seen at low load), so 0.8 s tells the two apart.
        long = [round(x, 3) for x in silences if x > 0.8]
        assert len(silences) >= 8, f"only {len(silences)} horizons without a gap"
        assert long == [], f"/audio silent at the horizon for {long} s"
    finally:
        source.close()


CAMERA = "/usb_cam/image_raw"


def unmeasured_silences(events: Sequence[object], horizon: float, topic: str
                        ) -> float | None:
    """How long ``topic`` has been silent at ``horizon`` as an observer sees it from the
    events handed out so far: ``None`` while a gap of it (or of everything) is open, else
    the time since its last arrival or the end of its last gap, whichever is later."""
    open_: set[float] = set()
    last = -float("inf")
    for e in events:
        if isinstance(e, MeasurementGap) and e.topic in (None, topic) and not e.graph:
            if e.end is None:
                open_.add(e.start)
            else:
                open_.discard(e.start)
                last = max(last, e.end)
        elif isinstance(e, MessageArrival) and e.topic == topic:
            last = max(last, e.time)
    return None if open_ else horizon - last


def test_a_stopped_subscriber_is_a_gap_from_where_the_counts_end_not_a_silence(
        robot: ThesisRobot) -> None:
    """SIGSTOP of ``/Signal_generator``, the camera's only on-robot subscriber: the source
    learns it only when that node's probe times out, a probe time-out after the round began,
    while the camera's counted arrivals end about where that round began. The stretch
    between is the black box's, not the camera's: the switch to a subscription must be a gap
    from where the counts end, handed out with the first horizon it reaches. Before, the gap
    began when the round ended and came with the horizon after that, so a horizon inside the
    stretch saw the camera silent for up to a probe time-out (a provisional period: the hz
    false alarm on the camera at a stall of /Signal_generator in the real campaign). A probe
    time-out of 0.95 s (under the 1 s a late poll may overrun before it is the black box's
    own pause) and horizons every 0.2 s make the stretch long and always polled."""
    source = Ros1Source(f"http://127.0.0.1:{robot.port}", Ros1Settings(probe_timeout=0.95))
    source.start(Interest(topics=frozenset({"/audio", CAMERA})))
    watch = Watch(source)
    both = {("/audio", "/audio_capture"), (CAMERA, "/usb_cam")}
    try:
        assert watch.until(lambda: both <= source.counted, 40), "the topics never counted"
        silences: list[float] = []
        for _ in range(3):
            os.kill(robot.pid("/Signal_generator"), signal.SIGSTOP)
            try:
                stopped = time.time()
                # fixed horizons, as the pipeline's evaluations: a poll that returns late
                # is followed at once by the horizons it overran
                for horizon in (stopped + 0.2 * k for k in range(1, 18)):
                    watch.events.extend(source.poll(horizon))
                    for topic in COUNTED:
                        silent = unmeasured_silences(watch.events, horizon, topic)
                        if silent is not None:
                            silences.append(silent)
            finally:
                os.kill(robot.pid("/Signal_generator"), signal.SIGCONT)
            assert watch.until(lambda: both <= source.counted, 20), "never counted again"
        # counted arrivals are queued a round (0.45 s) ahead, so a horizon normally finds
        # the last one at most a few periods old (0.05 s at low load); the stretch was the
        # probe time-out (0.95 s): horizons 0.55, 0.75 and 0.95 s into it before the fix
        long = sorted(round(x, 3) for x in silences if x > 0.6)
        assert len(silences) > 30, f"only {len(silences)} horizons outside gaps"
        assert long == [], f"counted topics silent at a horizon for {long} s"
    finally:
        source.close()
