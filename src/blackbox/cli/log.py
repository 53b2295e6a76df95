"""``blackbox log``: query, export (or salvage), check, purge and import the health log;
estimate its capacity."""

from __future__ import annotations

import argparse
import contextlib
import sqlite3
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, cast

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.record.check import check_log
from blackbox.record.export import FORMATS, export
from blackbox.record.logfile import classify
from blackbox.record.recorder import config_entry_row
from blackbox.record.retention import (
    ObservedCharacteristic,
    enforce_directory,
    estimate_capacity,
    hundred_topic_robot,
    thesis_robot,
)
from blackbox.record.salvage import NotALog, Salvaged, salvage, select
from blackbox.record.settings import DEFAULT_BUDGET, parse_size, recorder_settings
from blackbox.record.store import KINDS, LogEntry, StorageError, Store, StoreCorrupt
from blackbox.safetext import TerminalStream, terminal_text
from blackbox.timestamps import parse_timestamp

TIMELINE_FORMATS = ("svg", "png")
"""What ``log export --timeline`` draws (``--format`` or the output file's suffix)."""

EXIT_ERROR = 1
EXIT_USAGE = 2


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    log = subparsers.add_parser("log", help="query, export, purge or import the health log",
                                description="The black box's health log (see docs/recorder.md).")
    sub = log.add_subparsers(dest="log_command", metavar="ACTION", required=True)

    def with_db(p: argparse.ArgumentParser) -> None:
        p.add_argument("--db", type=Path, help="the health log file")
        p.add_argument("--config", type=Path,
                       help="configuration whose recorder.path names the health log")

    def with_filters(p: argparse.ArgumentParser) -> None:
        p.add_argument("--entity", help="node or topic (glob with * ? [])")
        p.add_argument("--characteristic", help="observer type (glob)")
        p.add_argument("--since", help="start time: seconds or ISO 8601 (inclusive)")
        p.add_argument("--until", help="end time: seconds or ISO 8601 (inclusive)")
        p.add_argument("--kind", action="append", default=[],
                       help=f"entry kind, repeatable or comma separated: {', '.join(KINDS)}")
        p.add_argument("--limit", type=int)

    def with_salvage(p: argparse.ArgumentParser) -> None:
        p.add_argument("--salvage", action="store_true",
                       help="read every intact entry of a damaged log, page by page, and "
                            "say what was lost (standard error)")

    q = sub.add_parser("query", help="print entries")
    with_db(q)
    with_filters(q)
    q.add_argument("--format", choices=["table", "jsonl"], default="table")
    with_salvage(q)
    q.set_defaults(func=_query)

    e = sub.add_parser("export", help="write entries as JSON lines, CSV or MCAP")
    with_db(e)
    with_filters(e)
    e.add_argument("--format", choices=[*FORMATS, *TIMELINE_FORMATS],
                   help="default: from the output file's suffix (svg and png: --timeline)")
    e.add_argument("-o", "--output", type=Path, help="output file (default: standard output)")
    e.add_argument("--timeline", action="store_true",
                   help="write the health timeline (one lane per entity) instead, as SVG "
                        "or PNG (--format or the output's suffix; default SVG)")
    with_salvage(e)
    e.set_defaults(func=_export)

    k = sub.add_parser("check", help="check the health log's integrity (exit 0 intact, 1 damaged)")
    with_db(k)
    k.set_defaults(func=_check)

    p = sub.add_parser("purge", help="empty the health log (asks for confirmation)")
    with_db(p)
    p.add_argument("--yes", action="store_true", help="do not ask")
    p.add_argument("--by", default="operator", help="who purges (recorded)")
    p.set_defaults(func=_purge)

    i = sub.add_parser("import", help="store a new configuration; a running black box applies it")
    with_db(i)
    i.add_argument("file", type=Path, help="configuration file (native or tug_observers)")
    i.add_argument("--note", default="", help="why (recorded with the version)")
    i.set_defaults(func=_import)

    c = sub.add_parser("capacity", help="how many operating hours a disk budget holds")
    c.add_argument("--config", type=Path, help="configuration to estimate for")
    c.add_argument("--robot", choices=["thesis", "100-topic"],
                   help="a reference robot instead of a configuration")
    c.add_argument("--observers", type=int, help="or: this many observers ...")
    c.add_argument("--every", type=float, default=1.0, help="... evaluated every S seconds")
    c.add_argument("--budget", help="disk budget, like '1 GB' (default: the configuration's "
                   "recorder.budget, else 1 GiB)")
    c.add_argument("--faults-per-hour", type=float, default=1.0)
    c.add_argument("--target-hours", type=float, default=4000.0)
    c.set_defaults(func=_capacity)


# ---- helpers ----------------------------------------------------------------------------------


def _fail(message: str, code: int = EXIT_ERROR) -> int:
    print(f"error: {message}", file=sys.stderr)
    return code


def _recorder_section(config: Path) -> ConfigNode | None:
    root = ConfigNode.load(config)
    if not root.is_map:
        raise root.error("not a configuration")
    return root.get("recorder")


def _db_path(args: argparse.Namespace) -> Path:
    if args.db is not None:
        db: Path = args.db
        return db
    if args.config is not None:
        return recorder_settings(_recorder_section(args.config), args.config.parent).path
    raise ConfigError("give the health log with --db FILE or --config FILE", "<command line>")


def parse_time(text: str | None) -> float | None:
    if text is None:
        return None
    try:
        return parse_timestamp(text)
    except ValueError:
        raise ValueError(f"not a time: {text!r} (seconds or ISO 8601)") from None


def _entries(args: argparse.Namespace, store: Store | Salvaged) -> list[LogEntry] | None:
    kinds = [k.strip() for arg in args.kind for k in arg.split(",") if k.strip()]
    try:
        if isinstance(store, Salvaged):
            return select(store.entries, entity=args.entity, characteristic=args.characteristic,
                          start=parse_time(args.since), end=parse_time(args.until),
                          kinds=kinds or None, limit=args.limit)
        return list(store.query(entity=args.entity, characteristic=args.characteristic,
                                start=parse_time(args.since), end=parse_time(args.until),
                                kinds=kinds or None, limit=args.limit))
    except ValueError as exc:
        _fail(str(exc), EXIT_USAGE)
        return None


def _open(args: argparse.Namespace, readonly: bool) -> Store | int:
    try:
        return Store.open(_db_path(args), readonly=readonly)
    except StoreCorrupt as exc:
        hint = " (read what is intact with --salvage)" if hasattr(args, "salvage") else ""
        return _fail(f"{exc}; see blackbox log check{hint}")
    except StorageError as exc:
        return _fail(str(exc))


def _salvaged(args: argparse.Namespace) -> Salvaged | int:
    """The intact entries of a damaged log, the report of what was lost on standard error."""
    path = _db_path(args)
    if classify(path) == "missing":
        return _fail(f"{path}: no such health log")
    try:
        found = salvage(path)
    except (NotALog, OSError) as exc:
        return _fail(f"{path}: cannot salvage: {exc}")
    for line in found.report.lines(found.entries):
        print(f"salvage: {line}", file=sys.stderr)
    return found


def _source(args: argparse.Namespace) -> Store | Salvaged | int:
    return _salvaged(args) if args.salvage else _open(args, readonly=True)


def _show_time(t: float) -> str:
    if t > 1e8:
        return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
    return f"{t:.3f}"


# ---- actions ------------------------------------------------------------------------------------


def _query(args: argparse.Namespace) -> int:
    store = _source(args)
    if isinstance(store, int):
        return store
    with _closing(store):
        entries = _entries(args, store)
        if entries is None:
            return EXIT_USAGE
        if args.format == "jsonl":
            export(entries, None, "jsonl", stdout=sys.stdout)
            return 0
        for e in entries:
            code = "" if e.code is None else str(e.code)
            summary = ", ".join(f"{k}={v}" for k, v in e.payload.items() if k != "text")
            print(terminal_text(f"{e.id:>8} {_show_time(e.time)} {e.kind:<14} "
                                f"{e.entity or '-':<28} {e.characteristic or '-':<10} "
                                f"{code:>3} {summary}"[:240]))
        print(f"{len(entries)} entries", file=sys.stderr)
    return 0


def _export(args: argparse.Namespace) -> int:
    if args.timeline:
        return _export_timeline(args)
    fmt = args.format
    if fmt in TIMELINE_FORMATS:
        return _fail(f"--format {fmt} draws the health timeline: add --timeline", EXIT_USAGE)
    if fmt is None:
        suffix = args.output.suffix.lstrip(".") if args.output else "jsonl"
        fmt = {"json": "jsonl", "ndjson": "jsonl"}.get(suffix, suffix)
        if fmt not in FORMATS:
            return _fail(f"cannot tell the format from {args.output}; give --format", EXIT_USAGE)
    store = _source(args)
    if isinstance(store, int):
        return store
    with _closing(store):
        entries = _entries(args, store)
        if entries is None:
            return EXIT_USAGE
        robot_id = store.robot_id if isinstance(store, Salvaged) else store.meta("robot_id")
        try:
            n = export(entries, args.output, fmt, robot_id or "",
                       stdout=cast(IO[str], TerminalStream(sys.stdout))
                       if sys.stdout.isatty() else sys.stdout)
        except (OSError, ValueError) as exc:
            return _fail(str(exc))
    if args.output:
        print(f"exported {n} entries to {args.output} ({fmt})", file=sys.stderr)
    return 0


def _export_timeline(args: argparse.Namespace) -> int:
    """The station's health timeline drawn from the robot's own log, as SVG or PNG."""
    from blackbox.station.timeline import build, from_log, svg

    suffix = args.output.suffix.lstrip(".").lower() if args.output else ""
    fmt = args.format or (suffix if suffix in TIMELINE_FORMATS else "svg")
    if fmt not in TIMELINE_FORMATS or (suffix and suffix not in TIMELINE_FORMATS):
        return _fail(f"--timeline writes SVG or PNG, not {fmt if fmt != 'svg' else suffix} "
                     "(--format svg|png, or an output ending .svg or .png)", EXIT_USAGE)
    if suffix and suffix != fmt:
        return _fail(f"--format {fmt} does not match the output {args.output.name}",
                     EXIT_USAGE)
    store = _source(args)
    if isinstance(store, int):
        return store
    with _closing(store):
        entries = _entries(args, store)
        if entries is None:
            return EXIT_USAGE
        robot_id = store.robot_id if isinstance(store, Salvaged) else store.meta("robot_id")
    if not entries:
        return _fail("no entries to draw (check --since/--until)")
    names, happenings = from_log(entries)
    start = parse_time(args.since) or min(e.time for e in entries)
    end = parse_time(args.until) or max(e.time for e in entries)
    if end <= start:
        end = start + 1.0
    lanes = build(robot_id or "robot", names, happenings, start, end)
    try:
        if fmt == "png":
            from blackbox.station.timeline_png import png
            picture = png(lanes, start, end)
            if args.output:
                args.output.write_bytes(picture)
            elif sys.stdout.isatty():
                return _fail("a PNG is not for the terminal: give -o FILE.png", EXIT_USAGE)
            else:
                sys.stdout.buffer.write(picture)
        elif args.output:
            args.output.write_text(svg(lanes, start, end) + "\n", encoding="utf-8")
        else:
            sys.stdout.write(svg(lanes, start, end) + "\n")
    except OSError as exc:
        return _fail(str(exc))
    if args.output:
        print(f"drew {len(names) + 1} lanes from {len(entries)} entries to {args.output} "
              f"({fmt})", file=sys.stderr)
    return 0


def _closing(store: Store | Salvaged) -> contextlib.AbstractContextManager[Any]:
    return store if isinstance(store, Store) else contextlib.nullcontext()


def _check(args: argparse.Namespace) -> int:
    path = _db_path(args)
    kind = classify(path)
    if kind in ("missing", "empty"):
        return _fail(f"{path}: {'no such' if kind == 'missing' else 'an empty'} health log")
    if kind == "foreign":
        return _fail(f"{path}: not a health log of this black box", EXIT_USAGE)
    result = check_log(path)
    for line in result.lines:
        print(line)
    return 0 if result.intact else EXIT_ERROR


def _purge(args: argparse.Namespace) -> int:
    store = _open(args, readonly=False)
    if isinstance(store, int):
        return store
    with store:
        n = store.count()
        if not args.yes:
            if not sys.stdin.isatty():
                return _fail("purge needs confirmation: run it in a terminal or pass --yes",
                             EXIT_USAGE)
            answer = input(f"Delete all {n} entries of {store.path}? Type 'purge' to confirm: ")
            if answer.strip() != "purge":
                print("nothing deleted")
                return EXIT_ERROR
        entry = store.purge(time.time(), by=args.by)
        removed = _purge_snapshots(args, store)
    print(f"purged {entry.payload['deleted']} entries and {removed} snapshot files; "
          f"recorded as entry {entry.id}")
    return 0


def _purge_snapshots(args: argparse.Namespace, store: Store) -> int:
    """Delete the snapshot files the recorder wrote (the log's manifest), nothing else."""
    directory = store.path.with_name(store.path.name + ".snapshots")
    if args.config is not None:
        directory = recorder_settings(_recorder_section(args.config),
                                      args.config.parent).snapshot_dir
    ours = store.snapshot_files()
    removed = enforce_directory(directory, 0, ours) if directory.is_dir() else []
    store.forget_snapshots(removed)
    return len(removed)


def validate_configuration(path: Path) -> str:
    """The file's text if it is a valid configuration (observers build), else ConfigError."""
    from blackbox.observe.build import build_observers, load_config

    build_observers(load_config(path))
    return path.read_text(encoding="utf-8")


def _import(args: argparse.Namespace) -> int:
    text = validate_configuration(args.file)
    store = _open(args, readonly=False)
    if isinstance(store, int):
        return store
    with store:
        row = config_entry_row(time.time(), text, "import", file=args.file.name, note=args.note)
        try:
            (eid,) = store.append([row])
        except sqlite3.Error as exc:
            return _fail(f"{store.path}: cannot store the configuration: {exc}")
        version = cast("dict[str, Any]", row.payload)["version"]  # written as a dict
    print(f"imported {args.file} as configuration version {version} (entry {eid}); "
          "a running black box applies it within its commit interval")
    return 0


def _capacity(args: argparse.Namespace) -> int:
    budget = DEFAULT_BUDGET
    policy = None
    share = 0.25
    if args.config is not None:
        from blackbox.observe.build import load_config

        loaded = load_config(args.config)
        observers = [_characteristic(node) for node in loaded.observers]
        section = loaded.sections.get("recorder")
        settings = recorder_settings(section, args.config.parent)
        budget = settings.budget_bytes
        policy = settings.policy
        share = settings.snapshot.share if settings.snapshot else 0.0
        name = str(args.config)
    elif args.robot == "thesis":
        observers, name = thesis_robot(), "thesis robot (3 nodes, 10 observers at 1 Hz)"
    elif args.robot == "100-topic":
        observers, name = hundred_topic_robot(), ("100-topic robot (200 topic and 50 node "
                                                  "observers at 1 Hz)")
    elif args.observers:
        observers = [ObservedCharacteristic(f"/entity_{i}", "hz", args.every)
                     for i in range(args.observers)]
        name = f"{args.observers} observers every {args.every:g} s"
    else:
        return _fail("give --config FILE, --robot thesis|100-topic or --observers N", EXIT_USAGE)
    if args.budget:
        try:
            budget = parse_size(args.budget)
        except ValueError as exc:
            return _fail(str(exc), EXIT_USAGE)
    log_budget = int(budget * (1 - share))
    est = estimate_capacity(observers, log_budget, policy, faults_per_hour=args.faults_per_hour)
    print(f"{name}: {est.observers} observers")
    print(f"  {est.entries_per_hour:,.0f} entries and {est.bytes_per_hour / 1e6:.3f} MB per "
          f"operating hour at {args.faults_per_hour:g} faults/h (measured on a simulated hour)")
    print(f"  budget {budget / 1e9:.3f} GB, of which {log_budget / 1e9:.3f} GB for the log"
          + (f" ({share:.0%} kept for snapshots)" if share else ""))
    print(f"  holds {est.hours:,.0f} operating hours before retention thins old samples")
    need = args.target_hours * est.bytes_per_hour / (1 - share)
    verdict = "meets" if est.hours >= args.target_hours else "misses"
    print(f"  {verdict} the {args.target_hours:,.0f} h target (needs {need / 1e9:.3f} GB)")
    return 0


def _characteristic(node: ConfigNode) -> ObservedCharacteristic:
    """The log's view of one observer entry: its size and subject come from its type."""
    from blackbox.observe.base import Subject, observer_kind

    kind = node["type"].str() if "type" in node else "observer"
    entity = "robot"
    for key in ("node", "topic", "topic_a", "interface"):
        child = node.get(key) if node.is_map else None
        if child is not None and not child.is_map:
            entity = str(child.raw)
            break
    every = node["every"].float(min=0, min_exclusive=True) if node.get("every") else 1.0
    registered = observer_kind(kind)
    if registered is None:  # not built, so not checked: size it as a typical observer
        return ObservedCharacteristic(entity, kind, every)
    return ObservedCharacteristic(entity, kind, every, registered.logged_values,
                                  on_node=registered.subject is Subject.NODE)
