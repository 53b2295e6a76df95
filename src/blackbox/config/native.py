"""The native configuration format: top-level ``observers`` plus one section per stage.

Only the shape is checked here (which top-level keys exist, that ``observers`` is a list of
mappings with a ``type``, the robot id). Each observer entry is validated by its factory and
each section by the stage that owns it, so the rules for a key live next to the code that
uses it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from blackbox.config.node import ConfigNode

FORMAT_VERSION = 1
DEFAULT_ROBOT_ID = "robot"
SECTIONS = ("robot", "diagnosis", "recorder", "transport", "station", "faults")
TOP_LEVEL_KEYS = ("version", "observers", *SECTIONS)


@dataclass(frozen=True, slots=True)
class NativeContent:
    observers: tuple[ConfigNode, ...]
    sections: Mapping[str, ConfigNode]
    robot_id: str
    warnings: tuple[str, ...]


def read_native(root: ConfigNode) -> NativeContent:
    """Split a native document into observer entries and stage sections."""
    root.check_keys(TOP_LEVEL_KEYS)
    version = root.get("version")
    if version is not None and version.int() != FORMAT_VERSION:
        raise version.error(f"unsupported format version {version.raw}; "
                            f"this black box reads version {FORMAT_VERSION}")
    warnings: list[str] = []
    observers: tuple[ConfigNode, ...] = ()
    where = root
    if "observers" in root:
        where = root["observers"]
        observers = tuple(observer_entries(where))
    if not observers:
        warnings.append(f"{where.file}:{where.line}: no observers; nothing will be observed")
    sections = {key: root[key] for key in SECTIONS if key in root}
    for key, node in sections.items():
        if not node.is_map and not node.is_null:
            raise node.error(f"the {key!r} section must be a mapping (key: value)")
    return NativeContent(observers, MappingProxyType(sections), robot_id(sections.get("robot")),
                         tuple(warnings))


def observer_entries(node: ConfigNode) -> list[ConfigNode]:
    """The entries of an ``observers`` list, each a mapping with a string ``type``."""
    if node.is_map:
        raise node.error("expected a list of observer entries ('- type: ...'), got a mapping")
    entries = node.list()
    for entry in entries:
        if not entry.is_map:
            raise entry.error("expected an observer entry (a mapping with 'type')")
        entry["type"].str()
    return entries


def robot_id(robot: ConfigNode | None) -> str:
    """The robot id of a ``robot`` section (``id``), ``"robot"`` when not given."""
    if robot is None or robot.is_null:
        return DEFAULT_ROBOT_ID
    node = robot.get("id")
    return node.str() if node is not None else DEFAULT_ROBOT_ID
