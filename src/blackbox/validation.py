"""Everything a configuration file must pass before a black box runs it, in one place.

``blackbox check-config`` and ``blackbox run`` both call :func:`check_config_file`, so a
file that check-config passes is a file run accepts: observers, the robot section, the
diagnosis model, the recorder settings, the transport settings (domain id, keys) and every
file the configuration names are all checked the same way, with the same one-line errors.
Nothing here opens a device, a socket or a log; it only reads and builds.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from blackbox.config.loader import LoadedConfig
from blackbox.config.node import MAX_FILE_BYTES, ConfigError, ConfigNode, read_bounded
from blackbox.diagnose.hybrid import make_diagnoser
from blackbox.diagnose.live import DiagnosisSettings
from blackbox.observe.base import Observer
from blackbox.observe.build import build_observers, load_config
from blackbox.record.settings import RecorderSettings

ROBOT_KEYS = ("id",)
NAMED_FILE_SUFFIX = "_file"
"""Keys ending so name a file (``public_key_file``): each must be a regular file of at
most :data:`~blackbox.config.node.MAX_FILE_BYTES`, checked before anything reads it."""


class NothingObserved(ConfigError):
    """The file is valid but observes nothing (a template): ``run`` refuses it."""

    def __init__(self, message: str, file: str, warnings: tuple[str, ...]) -> None:
        super().__init__(message, file)
        self.warnings = warnings


@dataclass(frozen=True, slots=True)
class CheckedConfig:
    """A configuration that passed every check ``run`` makes, with what the checks built."""

    config: LoadedConfig
    observers: list[Observer]
    diagnosis: DiagnosisSettings
    recorder: RecorderSettings | None
    """The ``recorder`` section's settings; ``None`` when the file has no such section."""
    transport: dict[str, Any] | None
    """The ``transport`` section as publisher arguments; ``None`` without the section."""


def check_config_file(path: str | Path, engine: str | None = None) -> CheckedConfig:
    """Read and check ``path`` as ``run`` will use it; the first problem is a ConfigError."""
    path = Path(path)
    config = load_config(path)
    observers = build_observers(config)
    if not observers:
        raise NothingObserved("the configuration observes nothing", str(path), config.warnings)
    base_dir = path.parent
    for node in named_files(config.sections.values()):
        file = Path(node.str())
        read_bounded(file if file.is_absolute() else base_dir / file, MAX_FILE_BYTES,
                     f"file named at {node.path}")
    robot = config.sections.get("robot")
    if robot is not None and robot.is_map:
        robot.check_keys(ROBOT_KEYS)
    diagnosis = DiagnosisSettings.from_config(config.sections.get("diagnosis"), base_dir)
    if diagnosis.enabled:
        try:
            make_diagnoser(observers, diagnosis, engine)
        except ValueError as exc:
            raise ConfigError(str(exc), str(path)) from None
    recorder = None
    if "recorder" in config.sections:
        recorder = RecorderSettings.from_config(config.sections["recorder"], base_dir)
    transport = None
    if "transport" in config.sections:
        from blackbox.transport.publisher import transport_options  # imports Cyclone DDS

        transport = transport_options(config.sections["transport"], base_dir)
    return CheckedConfig(config, observers, diagnosis, recorder, transport)


def named_files(nodes: Any) -> Iterator[ConfigNode]:
    """Every value under ``nodes`` whose key ends in ``_file``."""
    stack: list[ConfigNode] = list(nodes)
    while stack:
        node = stack.pop()
        if node.is_map:
            for key, child in node.items():
                if key.endswith(NAMED_FILE_SUFFIX) and not child.is_null \
                        and not child.is_map and not child.is_list:
                    yield child
                else:
                    stack.append(child)
        elif node.is_list:
            stack.extend(node.list())
