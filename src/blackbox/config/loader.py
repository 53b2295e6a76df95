"""Reading a configuration file in either format.

``load_config`` detects the format (native ``observers``, tug_observers ``setup``) and turns
both into the same :class:`LoadedConfig` of native observer entries. Every problem with the
file becomes a :class:`ConfigError` naming file, line, column and key path.

This package is a leaf: it parses and validates. The tug_observers forms of the observer
types come in as ``tug_forms`` (they live with the observers), and building observers from
the entries is :mod:`blackbox.observe.build`'s job.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Literal

import yaml

from blackbox.config.native import DEFAULT_ROBOT_ID, TOP_LEVEL_KEYS, read_native
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.config.tug import TugForm, translate_setup

Format = Literal["native", "tug"]
DocumentKind = Literal["native", "tug", "diagnosis"]

_TUG_KEY = "setup"
_DIAGNOSIS_KEYS = ("nodes", "observations")
_WHAT_IS_EXPECTED = ("expected a top-level 'observers' list (native format), a 'setup' list "
                     "(tug_observers format) or 'nodes' and 'observations' (diagnosis model)")


@dataclass(frozen=True, slots=True)
class LoadedConfig:
    """A configuration file read into native observer entries and stage sections."""

    file: str
    format: Format
    observers: tuple[ConfigNode, ...]
    sections: Mapping[str, ConfigNode] = field(default_factory=lambda: MappingProxyType({}))
    warnings: tuple[str, ...] = ()
    robot_id: str = DEFAULT_ROBOT_ID


def read_document(path: str | Path) -> ConfigNode:
    """The YAML document of ``path`` as config nodes; an empty file is an error."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError("is a directory, not a configuration file", str(p))
    try:
        root = ConfigNode.load(p)
    except yaml.MarkedYAMLError as exc:  # raised while building values, e.g. an unknown tag
        mark = exc.problem_mark or exc.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (0, 0)
        raise ConfigError(f"invalid YAML: {exc.problem or exc.context or exc}", str(p), line,
                          col) from None
    except (yaml.YAMLError, ValueError, RecursionError) as exc:
        raise ConfigError(f"invalid YAML: {exc}", str(p)) from None
    if root.is_null:
        raise root.error(f"the file is empty; {_WHAT_IS_EXPECTED}")
    if not root.is_map:
        raise root.error(f"not a configuration: {_WHAT_IS_EXPECTED}")
    return root


def document_kind(root: ConfigNode) -> DocumentKind:
    """Which kind of file ``root`` is, or one error saying what was expected."""
    keys = root.keys()
    if _TUG_KEY in keys:
        if "observers" in keys:
            raise root["observers"].error(
                "a file has either 'observers' (native format) or 'setup' "
                "(tug_observers format), not both")
        return "tug"
    if all(k in keys for k in _DIAGNOSIS_KEYS) and "observers" not in keys:
        return "diagnosis"
    if any(k in TOP_LEVEL_KEYS for k in keys):
        return "native"
    for key in keys:
        close = difflib.get_close_matches(key, [*TOP_LEVEL_KEYS, _TUG_KEY, *_DIAGNOSIS_KEYS], n=1)
        if close:
            raise root[key].error(f"unknown top-level key {key!r}; did you mean {close[0]!r}?")
    raise root.error(f"not a black box configuration: {_WHAT_IS_EXPECTED}")


TugForms = Mapping[str, TugForm | None]
"""The tug_observers form of each observer type (``None``: the type has none)."""


def load_config(path: str | Path, tug_forms: TugForms) -> LoadedConfig:
    """Read an observer configuration in the native or the tug_observers format."""
    return config_from_document(read_document(path), tug_forms)


def load_config_text(text: str, name: str, tug_forms: TugForms) -> LoadedConfig:
    """A configuration from text (an imported version); ``name`` appears in errors."""
    try:
        root = ConfigNode.parse(text, name)
    except (ValueError, RecursionError) as exc:
        raise ConfigError(f"invalid YAML: {exc}", name) from None
    if root.is_null or not root.is_map:
        raise root.error(f"not a configuration: {_WHAT_IS_EXPECTED}")
    return config_from_document(root, tug_forms)


def config_from_document(root: ConfigNode, tug_forms: TugForms) -> LoadedConfig:
    """Interpret a parsed YAML document as a configuration."""
    kind = document_kind(root)
    file = root.file
    if kind == "diagnosis":
        raise root.error("this is a diagnosis model (nodes and observations), not an observer "
                         "configuration; `blackbox check-config` lists its contents")
    if kind == "tug":
        root.check_keys([_TUG_KEY])
        translation = translate_setup(root[_TUG_KEY], tug_forms)
        if not translation.observers:
            warnings = (*translation.warnings,
                        f"{file}:{root.line}: no observers; nothing will be observed")
        else:
            warnings = translation.warnings
        return LoadedConfig(file, "tug", translation.observers, warnings=tuple(warnings))
    native = read_native(root)
    return LoadedConfig(file, "native", native.observers, native.sections, native.warnings,
                        native.robot_id)


@dataclass(frozen=True, slots=True)
class ModelNode:
    name: str
    subscribes: tuple[str, ...]
    publishes: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class ModelObservation:
    type: str
    resources: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class DiagnosisModelOutline:
    """What a diagnosis model (tug_diagnosis layout) names, for display only.

    The diagnosis stage reads and checks these files itself; this outline only lets
    ``check-config`` say what a file is when it is given one.
    """

    file: str
    nodes: tuple[ModelNode, ...]
    observations: tuple[ModelObservation, ...]


def outline_diagnosis_model(root: ConfigNode) -> DiagnosisModelOutline:
    nodes = []
    for node in root["nodes"].list():
        node.check_keys(["name", "sub_topic", "pub_topic"])
        nodes.append(ModelNode(
            node["name"].str(),
            node["sub_topic"].str_list() if "sub_topic" in node else (),
            node["pub_topic"].str_list() if "pub_topic" in node else ()))
    observations = []
    for obs in root["observations"].list():
        obs.check_keys(["type", "nodes", "topics"])
        found = obs.first("nodes", "topics")
        observations.append(ModelObservation(
            obs["type"].str(), found[1].str_list() if found else ()))
    return DiagnosisModelOutline(root.file, tuple(nodes), tuple(observations))
