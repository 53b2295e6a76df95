"""Composition of a black box from options: configuration, source, observers, sinks.

The command line, the demo, the tests and the benchmarks all build their black box here,
so there is exactly one place that knows how the stages plug together.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from blackbox.config.loader import LoadedConfig, build_observers, load_config
from blackbox.config.node import ConfigError
from blackbox.output.jsonlines import JsonLinesSink
from blackbox.output.live import LiveStatusView
from blackbox.pipeline import Pipeline, RunStats
from blackbox.sinks import Sink
from blackbox.sources import open_source

DEFAULT_CONFIG = Path(__file__).parent / "configs" / "thesis.yaml"


@dataclass
class RunOptions:
    """Everything ``blackbox run`` can be asked to do."""

    config: Path = DEFAULT_CONFIG
    source: str = "sim:thesis"
    duration: float | None = None
    simulated_clock: bool = False
    observations: Path | None = None
    diagnoses: Path | None = None
    events: Path | None = None
    live: bool = True
    live_interactive: bool | None = None
    faults: str | None = None
    seed: int = 1
    ground_truth: Path | None = None
    extra_sinks: list[Sink] = field(default_factory=list)


@dataclass
class BlackBox:
    """A composed black box, ready to run."""

    config: LoadedConfig
    pipeline: Pipeline
    options: RunOptions

    def run(self, stop: threading.Event | None = None) -> RunStats:
        return self.pipeline.run(self.options.duration, stop)


def source_options(options: RunOptions) -> dict[str, Any]:
    """Options for the source: the simulator takes clock, faults and seed; others nothing."""
    if not options.source.startswith("sim:"):
        if options.faults or options.simulated_clock:
            raise ConfigError("--faults and --simulated-clock need a simulated source (sim:...)",
                              "--source")
        return {}
    return {
        "realtime": not options.simulated_clock,
        "faults": options.faults,
        "seed": options.seed,
        "duration": options.duration,
        "ground_truth": options.ground_truth,
    }


def build(options: RunOptions) -> BlackBox:
    config = load_config(options.config)
    observers = build_observers(config)
    if not observers:
        raise ConfigError("the configuration observes nothing", str(options.config))
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
    source = open_source(options.source, **source_options(options))
    pipeline = Pipeline(source, observers, sinks)
    return BlackBox(config, pipeline, options)


@contextmanager
def graceful_interrupts() -> Iterator[threading.Event]:
    """A stop event set by SIGINT/SIGTERM, so Ctrl-C ends a run cleanly between steps."""
    stop = threading.Event()
    previous = {}

    def handler(signum: int, frame: object) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, handler)
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
