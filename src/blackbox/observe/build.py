"""Building observers from configuration: the registry's factories applied to the entries.

:mod:`blackbox.config` reads a file into native entries and knows no observer; here the
entries meet the observer types registered in :data:`~blackbox.observe.base.OBSERVERS`.
``load_config`` is the configuration reader with every registered type's tug_observers
form, so a tug file of a newly registered observer type loads like any other.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from pathlib import Path

from blackbox.config import loader
from blackbox.config.loader import LoadedConfig, TugForms
from blackbox.config.node import ConfigNode
from blackbox.config.tug import TugForm
from blackbox.model import Resource
from blackbox.observe.base import OBSERVERS, Observer, ObserverKind
from blackbox.observe.signals import GridUser, share_cells


def tug_forms() -> TugForms:
    """Every tug_observers group type the registered observer types translate."""
    forms: dict[str, TugForm | None] = {}
    for name, kind in OBSERVERS.items():
        for tug_name in kind.tug_names or (name,):
            forms[tug_name] = kind.tug
    return forms


def load_config(path: str | Path) -> LoadedConfig:
    """Read an observer configuration in the native or the tug_observers format."""
    return loader.load_config(path, tug_forms())


def load_config_text(text: str, name: str) -> LoadedConfig:
    """A configuration from text (an imported version); ``name`` appears in errors."""
    return loader.load_config_text(text, name, tug_forms())


def kind_of(entry: ConfigNode) -> ObserverKind:
    """The registered type of an entry, or an error naming the closest registered type."""
    type_node = entry["type"]
    name = type_node.str()
    kind = OBSERVERS.get(name)
    if kind is not None:
        return kind
    known = list(OBSERVERS)
    close = difflib.get_close_matches(name, known, n=1)
    if close:
        hint = f"did you mean {close[0]!r}?"
    else:
        hint = f"known: {', '.join(known)}" if known else "no observer types are installed"
    raise type_node.error(f"unknown observer type {name!r}; {hint}")


def build_observer(entry: ConfigNode) -> Observer:
    """The observer one native entry describes."""
    kind = kind_of(entry)
    try:
        return kind.build(entry)
    except (ValueError, OverflowError) as exc:  # rejected by a factory without a location
        raise entry.error(f"invalid {kind.name} observer: {exc}") from None


def build_observers(config: LoadedConfig) -> list[Observer]:
    """One observer per native entry; two entries observing the same characteristic (same
    type, same resource) are an error, since their records would be indistinguishable."""
    observers = [build_observer(entry) for entry in config.observers]
    reject_twins(config.observers, observers)
    share_cells(o for o in observers if isinstance(o, GridUser))
    return observers


def reject_twins(entries: Sequence[ConfigNode], observers: Sequence[Observer]) -> None:
    first: dict[tuple[str, Resource], ConfigNode] = {}
    for entry, observer in zip(entries, observers, strict=True):
        key = (observer.type_name, observer.resource)
        twin = first.setdefault(key, entry)
        if twin is not entry:
            raise entry.error(
                f"a second {observer.type_name} observer of {observer.resource.label()} "
                f"(the first is at line {twin.line}, {twin.path}); their records would share "
                "one identity: merge the two entries or observe different publisher groups")
