"""Composition of a black box from options: configuration, source, observers, sinks.

The command line, the demo, the tests and the benchmarks all build their black box here,
so there is exactly one place that knows how the stages plug together.
"""

from __future__ import annotations

import dataclasses
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, cast

from blackbox.config.loader import LoadedConfig
from blackbox.config.node import ConfigError
from blackbox.diagnose.hybrid import make_diagnoser
from blackbox.health.identity import EventLedger
from blackbox.model import BlackBoxEvent, Observation
from blackbox.observe.build import build_observers, load_config_text
from blackbox.output.jsonlines import JsonLinesSink
from blackbox.output.live import LiveStatusView
from blackbox.pipeline import Pipeline, RunStats
from blackbox.record.recorder import Recorder
from blackbox.record.settings import RecorderSettings
from blackbox.selfmonitor import ProbeObserver
from blackbox.sinks import Sink
from blackbox.sources import open_source
from blackbox.sources.base import (
    GroundTruthSource,
    RandomFaults,
    Source,
    SourceOptions,
    source_kind,
)
from blackbox.terminate import Terminated
from blackbox.validation import check_config_file

if TYPE_CHECKING:
    from blackbox.sources.sim import Fault
    from blackbox.transport.zenoh_bus import ZenohSettings

DEFAULT_CONFIG = Path(__file__).parent / "configs" / "thesis.yaml"


@dataclass(frozen=True, slots=True)
class RunOptions:
    """Everything ``blackbox run`` can be asked to do."""

    config: Path = DEFAULT_CONFIG
    source: str = "sim:thesis"
    duration: float | None = None
    simulated_clock: bool = False
    rate: float | None = None
    """A recording's replay speed in real time (recorded seconds per second)."""
    observations: Path | None = None
    diagnoses: Path | None = None
    events: Path | None = None
    live: bool = True
    live_interactive: bool | None = None
    faults: str | RandomFaults | Sequence[Fault] | None = None
    """A fault schedule file, ``"random"`` for a seeded campaign over the run, a campaign,
    or faults (for a source that injects faults)."""
    seed: int = 1
    ground_truth: Path | None = None
    diagnosis: bool = True
    record: Path | None = None
    force_record: bool = False
    """Start a new log over a file at ``record`` that is not a health log (moved aside)."""
    dds: bool = False
    dds_domain: int | None = None
    zenoh: ZenohSettings | None = None
    """Publish over Zenoh through these routers instead of DDS (with ``dds``)."""
    engine: str | None = None
    """Diagnosis engine (``cbd``, ``sfdd``, ``hybrid``); ``None``: the configuration's."""
    publish_diagnostics: bool = False
    """Publish the verdicts on ``/diagnostics`` of the watched ROS 1 master or ROS 2 domain
    (see ``docs/ros1.md``, ``docs/ros2.md``)."""
    extra_sinks: list[Sink] = field(default_factory=list)
    signing_key: Path | None = None
    """The robot's private key: sign what it publishes over DDS (docs/health.md)."""


@dataclass
class BlackBox:
    """A composed black box, ready to run."""

    config: LoadedConfig
    pipeline: Pipeline
    options: RunOptions

    def run(self, stop: threading.Event | None = None) -> RunStats:
        try:
            return self.pipeline.run(self.options.duration, stop)
        finally:
            self.write_ground_truth()

    def write_ground_truth(self) -> None:
        """Write the injected faults, if asked to and if the source knows them."""
        path = self.options.ground_truth
        source = self.pipeline.source
        if path is None or not source.capabilities.ground_truth:
            return
        from blackbox.sources.sim import write_ground_truth

        path.parent.mkdir(parents=True, exist_ok=True)
        write_ground_truth(cast(GroundTruthSource, source).ground_truth, path)


def source_options(options: RunOptions) -> SourceOptions:
    """The source's part of the run options; ``"random"`` faults span the run (or an hour)."""
    faults = options.faults
    if faults == "random":
        faults = RandomFaults(options.duration if options.duration is not None else 3600.0)
    return SourceOptions(realtime=not options.simulated_clock, seed=options.seed,
                         faults=faults, rate=options.rate)


def open_robot(options: RunOptions) -> Source:
    """Open the source; asking it for what it cannot do is a ``ConfigError``."""
    knows_truth = source_kind(options.source).capabilities.ground_truth
    if options.ground_truth is not None and not knows_truth:
        raise ConfigError(f"{options.source} knows no ground truth (--ground-truth needs a "
                          "source that injects faults, such as sim:...)", "--source")
    return open_source(options.source, source_options(options))


def build(options: RunOptions) -> BlackBox:
    checked = check_config_file(options.config, options.engine)
    config, observers = checked.config, checked.observers
    sinks: list[Sink] = []
    if options.live:
        sinks.append(LiveStatusView(title=f"blackbox {config.robot_id} on {options.source}",
                                    interactive=options.live_interactive))
    if options.observations is not None:
        sinks.append(JsonLinesSink(options.observations, diagnoses=False, events=False))
    if options.diagnoses is not None:
        sinks.append(JsonLinesSink(options.diagnoses, observations=False, events=False))
    if options.events is not None:
        sinks.append(JsonLinesSink(options.events, observations=False, diagnoses=False))
    sinks.extend(options.extra_sinks)
    source = open_robot(options)
    if options.publish_diagnostics:
        sinks.append(open_ros_diagnostics(options, config, source))
    recorder = None
    publishes = options.dds or options.zenoh is not None or "transport" in config.sections
    # One ledger for the health publisher and the recorder: a logged event carries the
    # identity it was published with (blackbox.health.identity).
    ledger = EventLedger() if publishes else None
    if options.record is not None or "recorder" in config.sections:
        recorder = open_recorder(options, config, source, ledger)
        sinks.append(recorder)
        observers.append(recorder_probe(recorder))
    settings = checked.diagnosis
    diagnoser = None
    if options.diagnosis and settings.enabled:
        try:
            diagnoser, extra = make_diagnoser(observers, settings, options.engine)
        except ValueError as exc:
            raise ConfigError(str(exc), str(options.config)) from None
        observers.extend(extra)
    pipelines: list[Pipeline] = []
    if publishes:
        dds = open_dds(options, config, recorder,
                       lambda: pipelines[0].evaluate_all() if pipelines else [], ledger)
        # Before the recorder: the publisher assigns the identities the recorder looks up.
        sinks.insert(sinks.index(recorder) if recorder is not None else len(sinks), dds)
    pipeline = Pipeline(source, observers, sinks, diagnoser=diagnoser)
    pipelines.append(pipeline)
    if recorder is not None:
        recorder.on_self_event = pipeline.emit_event
        recorder.on_config = lambda version: apply_config(pipeline, version.text,
                                                          f"imported version {version.version}")
        recorder.record_config(Path(options.config).read_text(encoding="utf-8"),
                               source=str(options.config))
    return BlackBox(config, pipeline, options)


def recorder_probe(recorder: Recorder) -> ProbeObserver:
    """The recorder's own health as an observation on the source's clock."""
    health = recorder.health()
    return ProbeObserver("recorder", health.resource,
                         lambda now: dataclasses.replace(recorder.health(), time=now))


def apply_config(pipeline: Pipeline, text: str, name: str) -> None:
    """Validate an imported configuration and swap its observers in without a restart.

    Raises ``ConfigError`` or ``ValueError`` when it cannot be applied; the recorder logs
    that as ``config_rejected`` and the running observers stay as they were.
    """
    observers = build_observers(load_config_text(text, name))
    recorder = next((o for o in pipeline.observers if isinstance(o, ProbeObserver)), None)
    pipeline.replace_observers([*observers, *([recorder] if recorder else [])])
    pipeline.emit_event(BlackBoxEvent(pipeline.source.now(), "config_applied",
                                      f"{name}: {len(observers)} observers now active"))


def open_dds(options: RunOptions, config: LoadedConfig, recorder: Recorder | None,
             on_ibit: Callable[[], Sequence[Observation]],
             ledger: EventLedger | None = None) -> Sink:
    """The UCMS health publisher; log requests are answered from the recorder's store."""
    from blackbox.health.describe import describe_observer
    from blackbox.transport.publisher import DdsHealthSink, transport_options

    kwargs = transport_options(config.sections.get("transport"), Path(options.config).parent)
    if options.dds_domain is not None:
        kwargs["domain_id"] = options.dds_domain
    if recorder is not None:
        kwargs.setdefault("log_store_path", recorder.path)
    if options.signing_key is not None:
        kwargs["signing_key_file"] = options.signing_key
    if options.zenoh is not None:
        kwargs["zenoh"] = dataclasses.replace(
            options.zenoh, partition=kwargs.get("partition", options.zenoh.partition))
    descriptions = [describe_observer(entry) for entry in config.observers]
    return DdsHealthSink(config.robot_id, descriptions=descriptions, on_ibit=on_ibit,
                         ledger=ledger, **kwargs)


def open_ros_diagnostics(options: RunOptions, config: LoadedConfig, source: Source) -> Sink:
    """The ``/diagnostics`` publisher on the middleware the source declares
    (``capabilities.diagnostics_bridge``): the watched ROS 1 master, the watched ROS 2
    domain, else ROS 2 on ``$ROS_DOMAIN_ID``."""
    import os

    from blackbox.health.describe import describe_observer

    descriptions = [describe_observer(e) for e in config.observers]
    bridge = source.capabilities.diagnostics_bridge
    if bridge == "ros1":
        from blackbox.output.ros1_diagnostics import Ros1DiagnosticsSink
        from blackbox.sources.ros1.source import Ros1Source

        if not isinstance(source, Ros1Source):
            raise ConfigError(f"{options.source} declares a ROS 1 diagnostics bridge but is "
                              "not a ROS 1 source", "--publish-diagnostics")
        return Ros1DiagnosticsSink(config.robot_id, source.master_uri,
                                   descriptions=descriptions)
    from blackbox.output.diagnostics import RosDiagnosticsSink
    from blackbox.sources.ros2 import domain_id_from_spec

    spec = options.source if bridge == "ros2" else "ros2"
    domain = domain_id_from_spec(spec, os.environ)
    return RosDiagnosticsSink(config.robot_id, domain_id=domain, descriptions=descriptions)


def open_recorder(options: RunOptions, config: LoadedConfig, source: Source,
                  ledger: EventLedger | None = None) -> Recorder:
    """The on-board store; snapshots are ROS 1 bags for ROS 1 robots, MCAP otherwise.

    A simulated clock waits for the disk when the recorder's queue is full (``block``);
    a real-time robot cannot wait, so the recorder drops the least valuable rows.
    """
    settings = RecorderSettings.from_config(config.sections.get("recorder"),
                                            Path(options.config).parent)
    snapshot = settings.snapshot
    if snapshot is not None and snapshot.format is None:
        snapshot = dataclasses.replace(snapshot, format=source.capabilities.snapshot_format)
    settings = settings.replace(
        path=options.record if options.record is not None else settings.path,
        snapshot=snapshot, replace_foreign=options.force_record,
        overflow="block" if options.simulated_clock else "drop")
    return Recorder(settings, robot_id=config.robot_id, schema_lookup=source.schema,
                    clock=source.now, ledger=ledger)


STOP_GRACE = 0.3
"""Seconds a SIGTERM leaves the running loop to stop between steps before it is cut short."""


@contextmanager
def graceful_interrupts() -> Iterator[threading.Event]:
    """A stop event set by SIGINT/SIGTERM, so Ctrl-C ends a run cleanly between steps.

    A second signal, or a SIGTERM whose stop the loop has not reached after
    :data:`STOP_GRACE` seconds (a step of a very large configuration can take longer),
    unwinds at once through the ``finally`` blocks: a service manager's SIGTERM is
    honoured within a second at every stage.
    """
    stop = threading.Event()
    previous = {}
    timers: list[threading.Timer] = []

    def handler(signum: int, frame: object) -> None:
        if stop.is_set():
            if signum == signal.SIGTERM:
                raise Terminated()
            raise KeyboardInterrupt
        stop.set()
        if signum == signal.SIGTERM:
            # A real signal to the main thread: it also cuts a sleep short (a real-time
            # source waiting for its next tick), which _thread.interrupt_main would not.
            timer = threading.Timer(STOP_GRACE, signal.pthread_kill,
                                    (threading.main_thread().ident, signal.SIGTERM))
            timer.daemon = True
            timers.append(timer)
            timer.start()

    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, handler)
    try:
        yield stop
    finally:
        for timer in timers:
            timer.cancel()
        for sig, old in previous.items():
            signal.signal(sig, old)
