"""``blackbox check-config FILE``: say what a configuration will observe, or what is wrong."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from blackbox.config.loader import (
    DiagnosisModelOutline,
    document_kind,
    outline_diagnosis_model,
    read_document,
)
from blackbox.observe.base import Observer
from blackbox.validation import NothingObserved, check_config_file

_FORMAT_NAMES = {"native": "native format", "tug": "tug_observers format"}


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "check-config",
        help="check a configuration file and list what it will observe",
        description="Check an observer configuration (native or tug_observers format) and "
                    "print one line per observer; a diagnosis model is listed instead. "
                    "Runs exactly the checks `blackbox run` makes before it starts. "
                    "On an error prints file:line:column, the key path and exits with 2.")
    parser.add_argument("file", metavar="FILE", help="YAML configuration file")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    root = read_document(args.file)
    if document_kind(root) == "diagnosis":
        print("\n".join(diagnosis_model_lines(outline_diagnosis_model(root))))
        return 0
    try:
        checked = check_config_file(args.file)  # exactly what `blackbox run` checks
    except NothingObserved as exc:
        for warning in exc.warnings:
            print(f"warning: {warning}", file=sys.stderr)
        raise
    config, observers = checked.config, checked.observers
    fmt = _FORMAT_NAMES[config.format]
    count = f"{len(observers)} observer{'' if len(observers) == 1 else 's'}"
    print(f"{config.file}: {fmt}, robot {config.robot_id!r}, {count}")
    for line in observer_lines(observers):
        print(line)
    if config.sections:
        print(f"sections: {', '.join(config.sections)}")
    for warning in config.warnings:
        print(f"warning: {warning}")
    return 0


def observer_lines(observers: Sequence[Observer]) -> list[str]:
    """Observers grouped by type in order of first appearance, one described line each."""
    groups: dict[str, list[Observer]] = {}
    for observer in observers:
        groups.setdefault(observer.type_name, []).append(observer)
    lines = []
    for type_name, members in groups.items():
        lines.append(f"{type_name} ({len(members)}):")
        lines.extend(f"  {observer.describe()}" for observer in members)
    return lines


def diagnosis_model_lines(model: DiagnosisModelOutline) -> list[str]:
    lines = [f"{model.file}: diagnosis model (not an observer configuration), "
             f"{len(model.nodes)} nodes, {len(model.observations)} observations",
             "nodes:"]
    for node in model.nodes:
        lines.append(f"  {node.name}: subscribes [{', '.join(node.subscribes)}], "
                     f"publishes [{', '.join(node.publishes)}]")
    lines.append("observations:")
    lines.extend(f"  {obs.type}: {', '.join(obs.resources)}" for obs in model.observations)
    return lines
