"""Fault-injection campaigns on real middleware: the demo robot as real processes.

The same seeded campaign as on the simulator (the simulator's ``random_campaign`` on the
thesis topology, so seed ``s`` gives the same faults at the same offsets), injected into the
real thesis robot (``scripts/ros1_robot``: ``roscore`` and three rospy nodes) by its fault
injector, which writes the ground truth line by line as faults begin and end. The black box
watches the robot through its ordinary source (``ros1://``) in this process, on the wall
clock, and is scored with the same episode definition (docs/evaluation.md). Its own CPU and
resident memory are sampled during the run.

A robot harness knows how to start a demo robot with an injector for one kind of source;
harnesses are registered by source scheme in :data:`ROBOT_HARNESSES`: ``ros1`` (Debian's
ROS 1, ``scripts/ros1_robot``) and ``ros2`` (rclpy nodes on Fast DDS from the ROS 2
wheels, ``scripts/ros2_robot``, on a fresh DDS domain per run).
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import selectors
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import psutil

from blackbox.app import RunOptions, build
from blackbox.events import Event, Interest, MeasurementGap, MessageArrival, TopicSchema
from blackbox.model import BlackBoxEvent, Diagnosis, Observation
from blackbox.pipeline import RunStats
from blackbox.registry import Registry
from blackbox.sinks import Collector
from blackbox.sources.base import Source
from blackbox.sources.sim import GroundTruth, Topology, random_campaign

REPO = Path(__file__).resolve().parents[3]
ROS1_ROBOT = REPO / "scripts" / "ros1_robot"
ROS2_ROBOT = REPO / "scripts" / "ros2_robot"
ROS_PYTHON = "/usr/bin/python3"


@dataclass(frozen=True, slots=True)
class ResourceUse:
    """The black box's own process during a run: CPU (percent of one core, mean over the
    run) and resident memory (bytes, mean and peak over 1 s samples)."""

    cpu_percent: float
    rss_mean: float
    rss_max: float
    seconds: float

    def to_dict(self) -> dict[str, float]:
        return {"cpu_percent": self.cpu_percent, "rss_mean": self.rss_mean,
                "rss_max": self.rss_max, "seconds": self.seconds}


class _ResourceMeter:
    """Samples this process's RSS once a second; CPU from its CPU times over the run."""

    def __init__(self, period: float = 1.0) -> None:
        self._proc = psutil.Process()
        self._period = period
        self._rss: list[int] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="eval-meter", daemon=True)
        self._t0 = 0.0
        self._cpu0 = 0.0

    def __enter__(self) -> _ResourceMeter:
        times = self._proc.cpu_times()
        self._cpu0 = times.user + times.system
        self._t0 = time.monotonic()
        self._thread.start()
        return self

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._rss.append(self._proc.memory_info().rss)
            self._stop.wait(self._period)

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    def result(self) -> ResourceUse:
        times = self._proc.cpu_times()
        seconds = max(time.monotonic() - self._t0, 1e-9)
        cpu = 100.0 * (times.user + times.system - self._cpu0) / seconds
        rss = self._rss or [self._proc.memory_info().rss]
        return ResourceUse(cpu, sum(rss) / len(rss), float(max(rss)), seconds)


class RecordingSource:
    """Passes a source's events through and keeps them, for replaying the same real run
    through other observer settings (the filter experiments).

    A kept message keeps its time, size and value but not its serialized bytes: a ROS 2
    arrival holds its payload for snapshots, and five minutes of a 15 Hz camera would keep
    4 GB alive. The value is taken at once, so only topics the pipeline decodes anyway are
    decoded."""

    def __init__(self, inner: Source) -> None:
        self.inner = inner
        self.name = inner.name
        self.capabilities = inner.capabilities
        self.events: list[Event] = []

    def start(self, interest: Interest) -> None:
        self.inner.start(interest)

    def now(self) -> float:
        return self.inner.now()

    def poll(self, until: float) -> list[Event]:
        events = self.inner.poll(until)
        self.events.extend(_without_payload(e) if type(e) is MessageArrival else e
                           for e in events)
        return events

    def schema(self, topic: str) -> TopicSchema | None:
        return self.inner.schema(topic)

    def close(self) -> None:
        self.inner.close()


@dataclass
class RealRun:
    """What one real run produced, before scoring: the observations and diagnoses from the
    scored part (``start`` to ``end``, wall clock), the ground truth, the recorded events
    and the black box's resource use."""

    start: float
    end: float
    truth: list[GroundTruth]
    observations: list[Observation]
    diagnoses: list[Diagnosis]
    events: list[Event]
    stats: RunStats
    resources: ResourceUse
    publishers: dict[str, str] = field(default_factory=dict)

    def gaps(self) -> list[dict[str, Any]]:
        """The measurement gaps the source reported (closed ones, as offsets from the scored
        start): what the black box left unjudged, and why (its own starvation, the host's,
        a switch, ...). Kept in the campaign's JSON so a run's false alarms and misses can
        be read against them."""
        return [{"start": round(e.start - self.start, 3), "end": round(e.end - self.start, 3),
                 "of": e.topic or e.node or ("graph" if e.graph else "everything"),
                 "reason": e.reason}
                for e in self.events if type(e) is MeasurementGap and e.end is not None]

    def reports(self) -> dict[str, int]:
        """How often the source reported each kind of its own findings (``ros1_behind``,
        ``ros1_host_saturated``, ``ros1_node_dead``, ...) during the run."""
        counts: dict[str, int] = {}
        for e in self.events:
            if isinstance(e, BlackBoxEvent):
                counts[e.kind] = counts.get(e.kind, 0) + 1
        return dict(sorted(counts.items()))


class RobotHarness(Protocol):
    """Starts a demo robot of one kind of source with its fault injector."""

    settle: float
    """Seconds the black box runs before the schedule starts (connections, discovery,
    filter windows; not scored)."""

    def topology(self) -> Topology:
        """The robot's nodes and topics, as the simulator knows them (same names)."""
        ...

    def running(self, schedule: Sequence[dict[str, Any]], truth: Path, log_dir: Path
                ) -> contextlib.AbstractContextManager[InjectedRobot]: ...


class InjectedRobot(Protocol):
    source: str
    """The ``--source`` spec the black box watches it with."""

    def go(self, t0: float) -> None:
        """Start the fault schedule at wall-clock ``t0``."""
        ...


ROBOT_HARNESSES: Registry[RobotHarness] = Registry("robot harness")


@dataclass
class _Injected:
    """An injector process that printed ``ready`` and waits for its start instant."""

    proc: subprocess.Popen[str]
    source: str

    def go(self, t0: float) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{t0!r}\n")
        self.proc.stdin.flush()


class Ros1ThesisHarness:
    """The real thesis robot under Debian ROS 1 (``scripts/ros1_robot/inject.py``)."""

    settle = 5.0

    def __init__(self, scripts: Path = ROS1_ROBOT, ready_timeout: float = 60.0) -> None:
        self.scripts = scripts
        self.ready_timeout = ready_timeout

    def topology(self) -> Topology:
        return Topology.thesis()

    def check(self) -> None:
        if not (self.scripts / "inject.py").is_file():
            raise ValueError(f"--source ros1: the demo robot's scripts are not in "
                             f"{self.scripts} (run from a source checkout)")
        if not Path(ROS_PYTHON).is_file() or _which("roscore") is None:
            raise ValueError("--source ros1: needs Debian's ROS 1 (roscore, rospy in "
                             f"{ROS_PYTHON}); run scripts/install-system-deps.sh")

    @contextlib.contextmanager
    def running(self, schedule: Sequence[dict[str, Any]], truth: Path, log_dir: Path
                ) -> Iterator[_Injected]:
        self.check()
        port = _free_port()
        plan = log_dir / "schedule.json"
        plan.write_text(json.dumps(list(schedule), indent=1), encoding="utf-8")
        out = (log_dir / "injector.log").open("w", encoding="utf-8")
        proc = subprocess.Popen(
            [ROS_PYTHON, str(self.scripts / "inject.py"), "--port", str(port), "--truth",
             str(truth), "--schedule", str(plan), "--log-dir", str(log_dir)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=out, text=True,
            start_new_session=True)
        try:
            wait_ready(proc, log_dir, self.ready_timeout, "ROS 1")
            yield _Injected(proc, f"ros1://127.0.0.1:{port}")
        finally:
            stop_process_group(proc)
            out.close()


def wait_ready(proc: subprocess.Popen[str], log_dir: Path, timeout: float, what: str) -> None:
    """Wait for an injector's ``ready`` line (its robot is up), then drain its output."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if sel.select(timeout=0.5):
                line = proc.stdout.readline()
                if line.startswith("ready"):
                    threading.Thread(target=_drain, args=(proc.stdout,), daemon=True).start()
                    return
                if not line and proc.poll() is not None:
                    break
    raise RuntimeError(f"the {what} demo robot did not start in {timeout:g} s; "
                       f"see {log_dir}/injector.log")


class Ros2ThesisHarness:
    """The thesis robot as rclpy nodes on Fast DDS (``scripts/ros2_robot/inject.py``), on a
    DDS domain of its own per run, loopback only; the black box reads it with Cyclone.

    The black box settles for 8 s: Fast DDS tells a late joiner which nodes a participant
    holds only at its next ``ros_discovery_info`` heartbeat (about 3 s), and until then the
    ROS 2 source has no graph (``activated`` says so with ``NOT_AVAILABLE``)."""

    settle = 8.0
    kinds = ("kill", "stall", "rate", "offset", "scale")

    def __init__(self, scripts: Path = ROS2_ROBOT, ready_timeout: float = 90.0,
                 domains: tuple[int, int] = (150, 230)) -> None:
        self.scripts = scripts
        self.ready_timeout = ready_timeout
        self.domains = domains

    def topology(self) -> Topology:
        return Topology.thesis()

    def check(self, schedule: Sequence[dict[str, Any]]) -> None:
        if not (self.scripts / "inject.py").is_file():
            raise ValueError(f"--source ros2: the demo robot's scripts are not in "
                             f"{self.scripts} (run from a source checkout)")
        try:
            import rclpy  # noqa: F401
        except ImportError:
            raise ValueError("--source ros2: needs the ROS 2 wheels (pip install ros-rclpy "
                             "ros-std-msgs ros-sensor-msgs ros-rmw-fastrtps-cpp; x86_64 "
                             "only)") from None
        unknown = sorted({f["kind"] for f in schedule} - set(self.kinds))
        if unknown:
            raise ValueError(f"--source ros2: the ROS 2 demo robot injects "
                             f"{', '.join(self.kinds)}, not {', '.join(unknown)}")

    @contextlib.contextmanager
    def running(self, schedule: Sequence[dict[str, Any]], truth: Path, log_dir: Path
                ) -> Iterator[_Injected]:
        self.check(schedule)
        domain = random.Random().randrange(*self.domains)
        plan = log_dir / "schedule.json"
        plan.write_text(json.dumps(list(schedule), indent=1), encoding="utf-8")
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   RMW_IMPLEMENTATION="rmw_fastrtps_cpp", AMENT_PREFIX_PATH=sys.prefix,
                   PYTHONUNBUFFERED="1")
        out = (log_dir / "injector.log").open("w", encoding="utf-8")
        proc = subprocess.Popen(
            [sys.executable, str(self.scripts / "inject.py"), "--domain", str(domain),
             "--truth", str(truth), "--schedule", str(plan), "--log-dir", str(log_dir)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=out, text=True, env=env,
            start_new_session=True)
        try:
            wait_ready(proc, log_dir, self.ready_timeout, "ROS 2")
            yield _Injected(proc, f"ros2:{domain}")
        finally:
            stop_process_group(proc)
            out.close()


def _without_payload(arrival: MessageArrival) -> MessageArrival:
    return MessageArrival(arrival.time, arrival.topic, arrival.publisher, arrival.size,
                          value=arrival.value)


def _drain(stream: Any) -> None:
    for _ in stream:
        pass


def stop_process_group(proc: subprocess.Popen[str]) -> None:
    """Stop a robot started in its own session: SIGTERM to its group, SIGKILL after 20 s."""
    if proc.poll() is None:
        with contextlib.suppress(OSError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(OSError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=5)
    if proc.stdin is not None:
        with contextlib.suppress(OSError):
            proc.stdin.close()


def _which(name: str) -> str | None:
    import shutil

    return shutil.which(name)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


ROBOT_HARNESSES.add("ros1", Ros1ThesisHarness())
ROBOT_HARNESSES.add("ros2", Ros2ThesisHarness())


def read_truth_log(path: Path) -> list[GroundTruth]:
    """Ground truth written as faults happen: a fault's last line wins (begin lines have no
    end; a fault whose end never came lasted to the end of the run)."""
    latest: dict[tuple[str, str, float], GroundTruth] = {}
    if not path.exists():
        return []
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.strip():
            g = GroundTruth.from_dict(json.loads(line))
            latest[(g.kind, g.component, g.start)] = g
    return sorted(latest.values(), key=lambda g: g.start)


def schedule_for(topology: Topology, *, duration: float, tail: float, seed: int,
                 kinds: Sequence[str], mean_gap: float, warmup: float,
                 separation: float) -> list[dict[str, Any]]:
    """The simulator's campaign for ``seed``, as offsets from the start of the scored run."""
    faults = random_campaign(topology, duration - tail, seed, tuple(kinds), mean_gap=mean_gap,
                             warmup=warmup, min_separation=separation)
    return [{"kind": f.kind, "component": f.component, "start": f.start, "end": f.end,
             "params": dict(f.params)} for f in faults]


def run_real(harness: RobotHarness, *, config: Path, duration: float, tail: float, seed: int,
             kinds: Sequence[str], mean_gap: float, warmup: float, separation: float,
             diagnosis: bool, settle: float | None = None, work_dir: Path | None = None,
             tick: Callable[[float], None] | None = None) -> RealRun:
    """One real run: start the robot, let the black box settle for ``settle`` seconds
    (the harness's by default; connections, filter windows; not scored), then ``duration``
    scored seconds with the seeded faults injected from their offsets."""
    settle = harness.settle if settle is None else settle
    schedule = schedule_for(harness.topology(), duration=duration, tail=tail, seed=seed,
                            kinds=kinds, mean_gap=mean_gap, warmup=warmup,
                            separation=separation)
    directory = Path(work_dir or tempfile.mkdtemp(prefix="blackbox-eval-"))
    directory.mkdir(parents=True, exist_ok=True)
    truth = directory / "truth.jsonl"
    sink = Collector()
    with harness.running(schedule, truth, directory) as robot:
        box = build(RunOptions(config=config, source=robot.source, duration=settle + duration,
                               live=False, diagnosis=diagnosis, extra_sinks=[sink]))
        recording = RecordingSource(box.pipeline.source)
        box.pipeline.source = recording
        stop = threading.Event()
        ticker = None
        if tick is not None:
            ticker = threading.Thread(target=_tick, args=(tick, stop), daemon=True)
            ticker.start()
        with _ResourceMeter() as meter:
            box.pipeline.start()
            t0 = box.pipeline.stats.started + settle
            robot.go(t0)
            stats = box.run()
        stop.set()
        resources = meter.result()
    topology = harness.topology()
    publishers = {t.name: t.publisher for t in topology.topics.values()}
    return RealRun(t0, stats.ended, read_truth_log(truth),
                   [o for o in sink.observations if o.time >= t0],
                   [d for d in sink.diagnoses if d.time >= t0],
                   recording.events, stats, resources, publishers)


def _tick(tick: Callable[[float], None], stop: threading.Event) -> None:
    started = time.monotonic()
    while not stop.wait(10.0):
        tick(time.monotonic() - started)
