"""Translation of tug_observers configurations (top-level ``setup``) into native entries.

The TU Graz tool groups observers by type (``setup[i].topics[j].callerids[k]``) and spells
some keys its own way. The black box has one flat list of native observer entries, so each
tug entry is expanded and renamed here, and nothing downstream knows tug existed.

Every node of the result is either an original node of the user's file or a synthetic node
created with ``at=`` an original one, so an error found later (a bad window size, an unknown
check type) still names the user's file, line and key path. The translation itself only
checks what it must understand to translate (structure, key names, rates); the values are
validated by the observer factories like any native entry.

The form of each observer type (which keys its groups have, how its quantities are spelled)
lives with that observer as a :data:`TugForm`; this module holds what the forms share and
hands every ``setup`` group to the form registered for its ``type``. It imports nothing
above ``config``: the forms are passed in.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from blackbox.config.node import ConfigNode

ROTATIONS = (("use_roll", "rot_x"), ("use_pitch", "rot_y"), ("use_yaw", "rot_z"))
AXES = ("x", "y", "z", "rot_x", "rot_y", "rot_z")
AXIS_FILTERS = tuple(f"{axis}_filter" for axis in AXES)
MOTION_QUANTITIES = {axis: axis for axis in AXES}
IGNORED = ("use_global_subscriber", "resource_topic")
"""Group keys of tug_observers that mean nothing to the black box."""
TUG_ACCELERATION_WINDOW = 7

TugForm = Callable[[ConfigNode, "TugTranslation"], None]
"""Translates one ``setup`` group of an observer type into native entries."""


@dataclass(frozen=True, slots=True)
class Translation:
    """Native observer entries made from a ``setup`` list, and what the user should know."""

    observers: tuple[ConfigNode, ...]
    warnings: tuple[str, ...]


def translate_setup(setup: ConfigNode, forms: Mapping[str, TugForm | None]) -> Translation:
    """Translate the value of a tug ``setup`` key (a list of observer groups).

    ``forms`` maps each group ``type`` to its translation; ``None`` marks a native observer
    type without a tug_observers form.
    """
    translation = TugTranslation()
    for group in setup.list():
        if not group.is_map:
            raise group.error("expected an observer group (a mapping with 'type'), "
                              f"got {'a list' if group.is_list else repr(group.raw)}")
        kind = group["type"]
        form = forms.get(kind.raw) if isinstance(kind.raw, str) else None
        if form is None and isinstance(kind.raw, str) and kind.raw in forms:
            raise kind.error(f"the {kind.raw} observer has no tug_observers form here; "
                             "write the file in the native format (docs/configuration.md)")
        if form is None:
            kind.str(choices=sorted(k for k, f in forms.items() if f is not None))
            continue
        form(group, translation)
    return Translation(tuple(translation.entries), tuple(translation.warnings))


def child(node: ConfigNode, key: str) -> ConfigNode | None:
    """The child at ``key`` even when it is null (a template's empty value has a location)."""
    if key not in node:
        return None
    return node[key]


def _where(node: ConfigNode) -> str:
    return f"{node.file}:{node.line}: at {node.path}"


def _scalar(value: object, at: ConfigNode) -> ConfigNode:
    return ConfigNode.scalar(value, at)


def entry(type_name: str, at: ConfigNode, **children: ConfigNode | None) -> ConfigNode:
    """A native observer entry; ``None`` children are left out (the native default applies)."""
    fields = {"type": _scalar(type_name, at)}
    fields.update({k: v for k, v in children.items() if v is not None})
    return ConfigNode.mapping(fields, at)


def every(group: ConfigNode) -> ConfigNode | None:
    """``main_loop_rate`` (Hz) as the native evaluation interval ``every`` (s)."""
    rate = group.get("main_loop_rate")
    if rate is None:
        return None
    return _scalar(1.0 / rate.float(min=0.0, min_exclusive=True), rate)


def publishers(callerid: ConfigNode | None, at: ConfigNode) -> ConfigNode:
    """A tug ``callerid`` as a native publisher group; ``[]`` or absent means all publishers."""
    if callerid is None or callerid.is_null:
        return ConfigNode.sequence([], callerid or at)
    items = callerid.list(allow_single=True)
    return ConfigNode.sequence([_scalar(item.str(), item) for item in items], callerid)


def filter_entry(node: ConfigNode | None) -> ConfigNode | None:
    """A tug filter as a native one: ``deviation_type`` is ``deviation``; empty is ``nofilter``."""
    if node is None:
        return None
    if node.is_null:
        return ConfigNode.mapping({"type": _scalar("nofilter", node)}, node)
    node.first("deviation_type", "deviation")
    fields: dict[str, ConfigNode] = {}
    for key, child in node.items():
        if child.is_null:
            continue
        fields["deviation" if key == "deviation_type" else key] = child
    if not fields:
        return ConfigNode.mapping({"type": _scalar("nofilter", node)}, node)
    return ConfigNode.mapping(fields, node)


def _value_check(node: ConfigNode) -> ConfigNode:
    """A value check with the tug spelling ``greather_than`` accepted for ``greater_than``."""
    if not node.is_map:
        return node
    fields: dict[str, ConfigNode] = {}
    for key, child in node.items():
        if key == "type" and child.raw == "greather_than":
            child = _scalar("greater_than", child)
        fields["greater_than" if key == "greather_than" else key] = child
    node.first("greather_than", "greater_than")
    return ConfigNode.mapping(fields, node)


def _check(node: ConfigNode) -> ConfigNode:
    """A hypothesis check; a template's empty ``value``/``deviation`` are left out."""
    if node.is_null:
        return ConfigNode.mapping({}, node)
    fields: dict[str, ConfigNode] = {}
    for key, child in node.items():
        if child.is_null:
            continue
        if key == "value":
            fields[key] = _value_check(child)
        elif key == "deviation":
            fields[key] = ConfigNode.sequence([_value_check(c) for c in child.list()], child)
        else:
            fields[key] = child
    return ConfigNode.mapping(fields, node)


def states(node: ConfigNode | None, quantities: Mapping[str, str],
            dropped: Iterable[str] = ()) -> ConfigNode | None:
    """Tug states (``state``, ``number``, quantities) as native ones (``name``, ``number``, ...).

    ``quantities`` maps each accepted tug spelling to its native quantity name; quantities in
    ``dropped`` are accepted and left out (a rotation switched off with ``use_yaw: false``).
    """
    if node is None or node.is_null:
        return None
    dropped = set(dropped)
    natives: dict[str, list[str]] = {}
    for tug_key, native_key in quantities.items():
        natives.setdefault(native_key, []).append(tug_key)
    out = []
    for state in node.list():
        state.check_keys(["state", "number", *quantities])
        name = state["state"]
        if name.is_map or name.is_list or name.is_null:
            raise name.error("expected the state name (a string)")
        fields: dict[str, ConfigNode] = {
            "number": state["number"],
            "name": name if isinstance(name.raw, str) else _scalar(str(name.raw), name),
        }
        for native_key, spellings in natives.items():
            present = [k for k in spellings if k in state]
            if len(present) > 1:
                raise state[present[1]].error(
                    f"{present[0]!r} and {present[1]!r} mean the same; give one")
            if present and native_key not in dropped:
                fields[native_key] = _check(state[present[0]])
        out.append(ConfigNode.mapping(fields, state))
    return ConfigNode.sequence(out, node)


def acceleration_window(*sources: tuple[ConfigNode, ConfigNode | None]) -> ConfigNode | None:
    """The one acceleration window of a velocity entry from tug's per-source windows.

    tug differentiates each velocity source over ``acceleartion_window_size`` messages
    (default 7); an imu measures acceleration itself and needs no window.
    """
    windows = [window if window is not None else _scalar(TUG_ACCELERATION_WINDOW, source)
               for source, window in sources if source["type"].raw != "imu"]
    if not windows:
        return None
    if any(w.raw != windows[0].raw for w in windows[1:]):
        raise windows[1].error(
            "the black box uses one acceleration window for both sources; source_A differentiates "
            f"over {windows[0].raw!r} messages, source_B over {windows[1].raw!r} "
            f"(tug's default is {TUG_ACCELERATION_WINDOW})")
    return windows[0]


class TugTranslation:
    """Native entries made so far and the warnings for the user; what a :data:`TugForm`
    writes into, with the layouts several forms share."""

    def __init__(self) -> None:
        self.entries: list[ConfigNode] = []
        self.warnings: list[str] = []

    def per_publisher_group(self, group: ConfigNode, native: str, group_keys: Iterable[str],
                            build: Callable[[ConfigNode], dict[str, ConfigNode | None]]) -> None:
        """``topics[].callerids[]``: one native entry per topic and publisher group."""
        group.check_keys(["type", "main_loop_rate", "topics", *IGNORED])
        rate = every(group)
        for topic in group["topics"].list():
            topic.check_keys(["name", "callerids"])
            name = topic["name"]
            name.str()
            groups = topic["callerids"].list()
            if not groups:
                raise topic["callerids"].error(
                    "no publisher group; use '- callerid: []' to observe all publishers")
            for callers in groups:
                callers.check_keys(["callerid", *group_keys])
                self.entries.append(entry(
                    native, callers, topic=name,
                    publishers=publishers(child(callers, "callerid"), callers),
                    every=rate, **build(callers)))

    def filtered_per_publisher_group(self, group: ConfigNode, native: str,
                                     quantities: Mapping[str, str]) -> None:
        """``topics[].callerids[]`` whose entries have one ``filter`` and ``states`` over the
        quantity spelled as the keys of ``quantities``."""
        self.per_publisher_group(group, native, ["filter", "states"], lambda c: {
            "filter": filter_entry(child(c, "filter")),
            "states": states(child(c, "states"), quantities)})

    def motion(self, item: ConfigNode) -> dict[str, ConfigNode | None]:
        """Axis filters and states of a velocity or moving entry.

        A rotation switched off (``use_yaw: false``) stays off, and its filter and state
        checks, which the original tool ignores, are left out.
        """
        dropped = [axis for switch, axis in ROTATIONS
                   if switch in item and not item[switch].bool()]
        fields: dict[str, ConfigNode | None] = {
            switch: item[switch] for switch, axis in ROTATIONS if axis in dropped}
        fields.update({f"{axis}_filter": filter_entry(child(item, f"{axis}_filter"))
                       for axis in AXES if axis not in dropped})
        fields["states"] = states(child(item, "states"), MOTION_QUANTITIES, dropped)
        return fields

    def source(self, item: ConfigNode, key: str, *, acceleration: bool
                ) -> tuple[ConfigNode | None, ConfigNode | None]:
        """A movement source as native ``{type, topic}`` and its acceleration window.

        ``(None, None)`` for a template source without a topic, which observes nothing.
        """
        node = item[key]
        if node.is_null or (node.is_map and node.get("topic") is None):
            self.warnings.append(f"{_where(node)}: template entry has no topic; "
                                 "it observes nothing until filled in")
            return None, None
        node.check_keys(["type", "topic", "velocity_window_size", "gravitation_cancelation",
                         "base_frame", "target_frame", *AXIS_FILTERS,
                         *(["acceleartion_window_size", "acceleration_window_size"]
                           if acceleration else [])])
        kind = node["type"]
        if kind.raw == "tf":
            raise kind.error("tf sources are not supported (the black box observes topics); "
                             "use an odometry, twist or imu topic")
        for axis_filter in AXIS_FILTERS:
            if node.get(axis_filter) is not None:
                raise node[axis_filter].error(
                    "per-source filters are not supported; filter the observed quantity with "
                    f"the entry's {axis_filter} instead")
        if node.get("velocity_window_size") is not None:
            self.warnings.append(f"{_where(node['velocity_window_size'])}: ignored; the black "
                                 "box differentiates with its own window")
        gravity = node.get("gravitation_cancelation")
        if gravity is not None and gravity.bool():
            self.warnings.append(f"{_where(gravity)}: ignored; gravitation is not cancelled")
        window = None
        if acceleration:
            found = node.first("acceleartion_window_size", "acceleration_window_size")
            window = found[1] if found else None
        return ConfigNode.mapping({"type": kind, "topic": node["topic"]}, node), window
