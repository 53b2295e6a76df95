"""``blackbox run``: watch a robot with the configured observers."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from blackbox.app import DEFAULT_CONFIG, RunOptions, build, graceful_interrupts
from blackbox.cli.router import add_tls_arguments, zenoh_settings
from blackbox.record.store import StorageError

EXIT_USAGE = 2
MAX_DOMAIN_ID = 232


def positive_seconds(text: str) -> float:
    """``--duration``: a finite number of seconds above zero."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def domain_id(text: str) -> int:
    """``--domain``: a DDS domain id, 0..232 (what Cyclone can map to ports)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise argparse.ArgumentTypeError(f"must be 0..{MAX_DOMAIN_ID}, got {value}")
    return value


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("run", help="watch a robot: observe, diagnose, record",
                       description="Watch a robot with the observers of a configuration file.")
    add_run_arguments(p)
    p.set_defaults(func=run_command)


def add_run_arguments(p: argparse.ArgumentParser, default_config: Path = DEFAULT_CONFIG) -> None:
    p.add_argument("--config", type=Path, default=default_config,
                   help="native or tug_observers YAML (default: the thesis robot's observers)")
    p.add_argument("--source", default="sim:thesis",
                   help="sim:thesis, sim:TOPOLOGY.yaml, ros1, ros1://HOST:PORT or bag:FILE "
                        "(a ROS 1 bag, rosbag2 directory or MCAP file; docs/bags.md)")
    p.add_argument("--duration", type=positive_seconds, default=None, metavar="S",
                   help="stop after S seconds of source time (default: until Ctrl-C)")
    p.add_argument("--simulated-clock", action="store_true",
                   help="run a simulated source or a bag as fast as possible instead of in "
                        "real time")
    p.add_argument("--rate", type=float, default=None, metavar="X",
                   help="bag only: replay in real time at X recorded seconds per second")
    p.add_argument("--faults", default=None, metavar="FILE|random",
                   help="simulator only: a fault schedule YAML, or 'random' for a seeded campaign")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulator and its faults")
    p.add_argument("--ground-truth", type=Path, default=None, metavar="FILE",
                   help="simulator only: write injected faults as JSON lines")
    p.add_argument("--observations", type=Path, default=None, metavar="FILE",
                   help="write every observation as JSON lines (schema: docs/observations.md)")
    p.add_argument("--diagnoses", type=Path, default=None, metavar="FILE",
                   help="write every diagnosis as JSON lines (schema: docs/observations.md)")
    p.add_argument("--events", type=Path, default=None, metavar="FILE",
                   help="write the black box's own events as JSON lines")
    p.add_argument("--record", type=Path, default=None, metavar="DB",
                   help="keep the health log in this SQLite file (see docs/recorder.md); an "
                        "existing file that is not a health log is refused")
    p.add_argument("--force", action="store_true",
                   help="with --record: move a file that is not a health log aside and start "
                        "a new log (never overwritten)")
    p.add_argument("--dds", action="store_true",
                   help="publish UCMS health over DDS (loopback unless configured; docs/health.md)")
    p.add_argument("--domain", type=domain_id, default=None, metavar="ID",
                   help="DDS domain id (default: transport.domain_id, else 0)")
    p.add_argument("--zenoh", action="append", default=None, metavar="ENDPOINT",
                   help="publish the same health over Zenoh through this router (e.g. "
                        "tcp/router.example:7447; repeatable) instead of DDS: for a station "
                        "on another network (docs/station.md, Fleet deployment)")
    add_tls_arguments(p)
    p.add_argument("--key", type=Path, default=None, metavar="FILE",
                   help="the robot's private key (blackbox keygen --robot): sign every "
                        "health sample, log reply and IBIT result it publishes over DDS")
    p.add_argument("--publish-diagnostics", action="store_true",
                   help="also publish the verdicts as diagnostic_msgs/DiagnosticArray on "
                        "/diagnostics: with --source ros1 registers with that ROS 1 master "
                        "(docs/ros1.md), else ROS 2 on the domain of --source ros2:N or "
                        "$ROS_DOMAIN_ID (docs/ros2.md)")
    p.add_argument("--quiet", action="store_true", help="no live status view")
    p.add_argument("--metrics", default=None, metavar="HOST:PORT",
                   help="serve the black box's own figures at http://HOST:PORT/metrics "
                        "(Prometheus text format; docs/station.md \"Metrics\")")


def options_from_args(args: argparse.Namespace) -> RunOptions:
    return RunOptions(
        config=args.config, source=args.source, duration=args.duration,
        simulated_clock=args.simulated_clock, rate=args.rate, observations=args.observations,
        diagnoses=args.diagnoses, events=args.events, live=not args.quiet,
        faults=args.faults, seed=args.seed, ground_truth=args.ground_truth,
        record=args.record, force_record=args.force, dds=args.dds, dds_domain=args.domain,
        publish_diagnostics=args.publish_diagnostics, signing_key=args.key,
        zenoh=zenoh_settings(args),
    )


def run_command(args: argparse.Namespace) -> int:
    if args.key is not None:
        from blackbox.transport.auth import RequestAuthError, load_private_key

        try:
            load_private_key(args.key)
        except RequestAuthError as exc:
            print(f"error: --key: {exc}", file=sys.stderr)
            return EXIT_USAGE
    from blackbox.output.metrics import MetricsServer, RobotMetrics

    options = options_from_args(args)
    metrics = RobotMetrics() if getattr(args, "metrics", None) else None
    server = None
    if metrics is not None:
        host, sep, port = str(args.metrics).rpartition(":")
        if not sep or not port.isdigit() or int(port) > 65535:
            print(f"error: --metrics wants HOST:PORT, got {args.metrics!r}", file=sys.stderr)
            return EXIT_USAGE
        options.extra_sinks.append(metrics)
    try:
        blackbox = build(options)
    except StorageError as exc:  # the record path cannot be used: nothing was touched
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if metrics is not None:
        metrics.pipeline = blackbox.pipeline
        try:
            server = MetricsServer(metrics, host.strip("[]") or "127.0.0.1", int(port))
        except OSError as exc:
            print(f"error: --metrics: cannot listen on {args.metrics}: {exc.strerror}",
                  file=sys.stderr)
            return EXIT_USAGE
        server.start()
        print(f"blackbox: metrics at http://{host or '127.0.0.1'}:{server.port}/metrics",
              file=sys.stderr, flush=True)
    try:
        with graceful_interrupts() as stop:
            stats = blackbox.run(stop)
    finally:
        if server is not None:
            server.stop()
    span = stats.ended - stats.started
    print(f"blackbox: {span:.1f} s observed, {stats.messages:,} messages, "
          f"{stats.observations:,} observations ({stats.faulty_observations:,} faulty), "
          f"{stats.diagnoses} diagnoses, {stats.errors} internal errors", file=sys.stderr)
    return 0
