"""A bag recorded from a live run, replayed, gives the live run's observations and diagnoses.

The real thesis robot (Debian ROS 1, scripts/ros1_robot) runs with two faults injected into
its processes while Debian's ``rosbag record`` records its topics and the black box watches
it live. Replaying the bag on a simulated clock from the live run's start must write the
same observation records (same evaluation times; same verdicts except within a second of a
verdict change, where one message more or less in a window can tip it; values within a
small tolerance) and the same sequence of diagnoses within a second.

Known, documented differences the comparison leaves out: the first 5 s (the live black box
needs a graph round and its TCPROS connections before it hears messages the bag already
has) and anything a bag cannot know (node liveness, resources): the configuration observes
topics only. A bag records no subscribers, so both runs use the same diagnosis model file.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import psutil
import pytest

from blackbox.app import RunOptions, build
from blackbox.output.jsonlines import read_records
from blackbox.sources.cpu_wait import WaitMeter

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts" / "ros1_robot"))
from inject import Injector
from robot import ThesisRobot, free_port

from stall_monitor import StallMonitor

pytestmark = [pytest.mark.ros1, pytest.mark.slow,
              pytest.mark.skipif(shutil.which("rosbag") is None, reason="needs Debian's ROS 1")]

TOPICS = ["/audio", "/signal"]
WINDOW = 10
"""Periods in the rate observers' mean filter (the configuration below)."""
LAG = 0.075
"""How much later than the bag's recorder the live black box may take a message under load
(a little more than one period of /signal, the slower topic)."""
CONFIG = """
version: 1
robot: {id: thesis-robot}
observers:
  - type: hz
    topic: /audio
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.03, std_deviation: 0.01}}}
  - type: hz
    topic: /signal
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.0666667, std_deviation: 0.01}}}
  - {type: timeout, topic: /audio, timeout: 1.0}
  - {type: timeout, topic: /signal, timeout: 1.0}
  - type: scores
    topic: /signal
    field: data
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, score: {value: {type: gauss, mean: 15.0, std_deviation: 0.5}}}
diagnosis:
  model: model.yaml
"""
MODEL = """
nodes:
  - {name: /usb_cam, pub_topic: [/usb_cam/image_raw]}
  - {name: /audio_capture, pub_topic: [/audio]}
  - {name: /Signal_generator, pub_topic: [/signal], sub_topic: [/usb_cam/image_raw, /audio]}
observations:
  - {type: hz, topics: [/audio, /signal]}
  - {type: timeout, topics: [/audio, /signal]}
  - {type: scores, topics: [/signal]}
"""
WARMUP = 5.0
TRANSITION = 1.0  # seconds around a live verdict change where the replay may differ
SCHEDULE = [(8.0, 14.0, "rate", "/audio", {"hz": 10.0}),
            (18.0, 24.0, "offset", "/signal", {"value": 5.0})]
DURATION = 30.0


def default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class RecorderWaits:
    """Run-queue waits of ``rosbag record``'s processes, sampled every 0.05 s while it runs.

    The recorder stamps a message when its callback gets to run: a recorder kept off the
    CPU for 0.1 s stamps the message that arrived before it 0.1 s late. Seen once:
    ``silent_for`` 0.1 s live against 0.00003 s replayed on /audio while the machine as a
    whole did not stall (:class:`StallMonitor` saw nothing); the recorder's own lateness is
    the likely cause, not measured in that run. Its run-queue waits bound that lateness."""

    def __init__(self) -> None:
        self._spans: list[tuple[float, float, float]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def watch(self, pid: int) -> None:
        self._thread = threading.Thread(target=self._sample, args=(pid,), daemon=True)
        self._thread.start()

    def _sample(self, pid: int) -> None:
        meter = WaitMeter()
        then = time.time()
        while not self._stop.wait(0.05):
            try:
                pids = [pid] + [c.pid for c in psutil.Process(pid).children(recursive=True)]
            except psutil.Error:
                return
            now = time.time()
            waits = [meter.threads_since_last(p, now) or {} for p in pids]
            worst = max((w for per in waits for w in per.values()), default=0.0)
            with self._lock:
                self._spans.append((then, now, worst))
            then = now

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def waited(self, start: float, end: float) -> float:
        """Seconds the recorder's most delayed thread waited in samples touching
        ``[start, end]``."""
        with self._lock:
            return sum(w for a, b, w in self._spans if b >= start and a <= end)


def record_live(tmp: Path, config: Path, stalls: StallMonitor,
                waits: RecorderWaits) -> tuple[Path, float, float]:
    """Live run with faults, recorded by ``rosbag record``: the bag, start and end times.
    ``stalls`` runs meanwhile: the recorder stamps each message when it gets to run, so
    a machine that stopped scheduling processes moves the bag's times by that long."""
    robot = ThesisRobot(free_port(), log_dir=tmp / "logs").start()
    recorder: subprocess.Popen[bytes] | None = None
    try:
        log = (tmp / "logs" / "rosbag.log").open("wb")
        recorder = subprocess.Popen(
            ["rosbag", "record", "-O", str(tmp / "live.bag"), *TOPICS, "__name:=bag_recorder"],
            env=robot.env, cwd=tmp, stdout=log, stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=default_sigint)
        waits.watch(recorder.pid)
        deadline = time.monotonic() + 30
        while not (tmp / "live.bag.active").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert (tmp / "live.bag.active").exists(), "rosbag record did not start"
        time.sleep(2.0)  # its subscriptions connect
        box = build(RunOptions(config=config, source=f"ros1://127.0.0.1:{robot.port}?counters=0",
                               observations=tmp / "live.obs.jsonl",
                               diagnoses=tmp / "live.diag.jsonl", live=False))
        stop = threading.Event()
        thread = threading.Thread(target=box.run, args=(stop,), daemon=True)
        thread.start()
        while box.pipeline.stats.started == 0.0:
            time.sleep(0.01)
        started = box.pipeline.stats.started
        injector = Injector(robot)
        for begin, end, kind, component, params in SCHEDULE:
            time.sleep(max(0.0, started + begin - time.time()))
            fault = injector.begin(kind, component, **params)
            time.sleep(max(0.0, started + end - time.time()))
            injector.end(fault)
        time.sleep(max(0.0, started + DURATION - time.time()))
        stop.set()
        thread.join(timeout=10)
        ended = box.pipeline.stats.ended
        time.sleep(1.0)
    finally:
        waits.stop()
        if recorder is not None:
            os.killpg(recorder.pid, signal.SIGINT)
            recorder.wait(timeout=20)
        robot.stop()
    assert (tmp / "live.bag").exists(), "rosbag record did not close its bag"
    return tmp / "live.bag", started, ended


def by_key(path: Path, since: float, until: float) -> dict[tuple[str, str, float], Any]:
    out = {}
    for r in read_records(path):
        if since <= r["time"] <= until:
            out[(r["observer"], json.dumps(r["resource"], sort_keys=True),
                 round(r["time"], 3))] = r
    return out


def changes(records: dict[tuple[str, str, float], Any]) -> dict[tuple[str, str], list[float]]:
    """Times at which each observer's verdict changed."""
    series: dict[tuple[str, str], list[tuple[float, int]]] = defaultdict(list)
    for (obs, res, t), r in sorted(records.items(), key=lambda kv: kv[0][2]):
        series[(obs, res)].append((t, r["code"]))
    return {k: [t for (t, c), (_, p) in zip(v[1:], v, strict=False) if c != p]
            for k, v in series.items()}


def diagnosis_steps(path: Path, since: float, until: float) -> list[tuple[float, list[Any]]]:
    steps: list[tuple[float, list[Any]]] = []
    for r in read_records(path):
        if since <= r["time"] <= until:
            cands = sorted(sorted(c) for c in r["candidates"])
            if not steps or steps[-1][1] != cands:
                steps.append((r["time"], cands))
    return steps


def test_replaying_the_bag_of_a_live_run_gives_its_observations_and_diagnoses(
        tmp_path: Path) -> None:
    config = tmp_path / "observers.yaml"
    config.write_text(CONFIG)
    (tmp_path / "model.yaml").write_text(MODEL)
    waits = RecorderWaits()
    with StallMonitor() as stalls:
        bag, started, ended = record_live(tmp_path, config, stalls, waits)
    replay = build(RunOptions(config=config, source=f"bag:{bag}?start={started!r}",
                              simulated_clock=True, duration=ended - started,
                              observations=tmp_path / "bag.obs.jsonl",
                              diagnoses=tmp_path / "bag.diag.jsonl", live=False))
    replay.run()
    since, until = started + WARMUP, ended
    live = by_key(tmp_path / "live.obs.jsonl", since, until)
    again = by_key(tmp_path / "bag.obs.jsonl", since, until)
    assert len(live) > 100
    assert set(again) == set(live), "the same observers evaluated at the same times"

    live_changes = changes(live)
    differing = []
    tipped = 0
    for key, rec in live.items():
        other = again[key]
        near_change = any(abs(key[2] - t) <= TRANSITION for t in live_changes[key[:2]])
        if rec["code"] != other["code"]:
            if not near_change:
                differing.append((key, rec["code"], other["code"]))
            tipped += 1
            continue
        for name, value in rec["values"].items():
            replayed = other["values"][name]
            # A window's deviation (period_deviation, score_deviation) moves a lot with one
            # message more or less in its ten: live delivery lag under load shifts the
            # window by a message where the bag's does not (0.30 vs 0.37 seen beside a
            # fault's end). Its verdict (above) and its mean are still compared.
            if not isinstance(value, float) or near_change or name.endswith("_deviation"):
                continue
            # a message that landed within the live delivery lag before an evaluation is
            # counted there in the bag but at the next evaluation live: ``silent_for`` may
            # then differ by one period of the topic (at most 0.0667 s here)
            if name == "rate_hz":
                # the mean of ten periods: live delivery lag under load moves the window's
                # edge messages by up to that lag (37.4 live vs 33.3 replayed Hz on /audio
                # seen at load 12: spans of 0.268 and 0.300 s), so the spans are compared
                # plus any machine stall over the window, which moves the bag's stamps
                span, span_again = WINDOW / value, WINDOW / replayed
                start = key[2] - max(span, span_again) - LAG
                stalled = stalls.stalled(start, key[2]) + waits.waited(start, key[2])
                assert span_again == pytest.approx(span, abs=LAG + stalled), \
                    (key, name, value, replayed, stalled)
                continue
            slack = (LAG + stalls.stalled(key[2] - 1.0, key[2])
                     + waits.waited(key[2] - 1.0, key[2])) if name == "silent_for" else 0.05
            assert replayed == pytest.approx(value, rel=0.05, abs=slack), (key, name)
    print(f"{len(live)} observations compared, {tipped} verdicts differ within "
          f"{TRANSITION} s of a live verdict change")
    assert not differing, differing
    faulty = {k[0] for k, r in live.items() if r["faulty"]}
    assert {"hz", "scores"} <= faulty, "both injected faults were seen live"

    live_steps = diagnosis_steps(tmp_path / "live.diag.jsonl", since, until)
    bag_steps = diagnosis_steps(tmp_path / "bag.diag.jsonl", since, until)
    print("live diagnoses:", [(round(t - started, 2), c) for t, c in live_steps])
    print("bag diagnoses: ", [(round(t - started, 2), c) for t, c in bag_steps])
    assert [c for _, c in bag_steps] == [c for _, c in live_steps]
    assert all(abs(a - b) <= TRANSITION
               for (a, _), (b, _) in zip(bag_steps, live_steps, strict=True))
