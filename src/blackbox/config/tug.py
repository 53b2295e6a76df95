"""Translation of tug_observers configurations (top-level ``setup``) into native entries.

The TU Graz tool groups observers by type (``setup[i].topics[j].callerids[k]``) and spells
some keys its own way. The black box has one flat list of native observer entries, so each
tug entry is expanded and renamed here, and nothing downstream knows tug existed.

Every node of the result is either an original node of the user's file or a synthetic node
created with ``at=`` an original one, so an error found later (a bad window size, an unknown
check type) still names the user's file, line and key path. The translation itself only
checks what it must understand to translate (structure, key names, rates); the values are
validated by the observer factories like any native entry.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from blackbox.config.node import ConfigNode

_ROTATIONS = (("use_roll", "rot_x"), ("use_pitch", "rot_y"), ("use_yaw", "rot_z"))
_AXES = ("x", "y", "z", "rot_x", "rot_y", "rot_z")
_AXIS_FILTERS = tuple(f"{axis}_filter" for axis in _AXES)
_MOTION_QUANTITIES = {axis: axis for axis in _AXES}
_IGNORED = ("use_global_subscriber", "resource_topic")
TUG_ACCELERATION_WINDOW = 7


@dataclass(frozen=True, slots=True)
class Translation:
    """Native observer entries made from a ``setup`` list, and what the user should know."""

    observers: tuple[ConfigNode, ...]
    warnings: tuple[str, ...]


def translate_setup(setup: ConfigNode) -> Translation:
    """Translate the value of a tug ``setup`` key (a list of observer groups)."""
    translator = _Translator()
    for group in setup.list():
        translator.group(group)
    return Translation(tuple(translator.entries), tuple(translator.warnings))


def _child(node: ConfigNode, key: str) -> ConfigNode | None:
    """The child at ``key`` even when it is null (a template's empty value has a location)."""
    if key not in node:
        return None
    return node[key]


def _where(node: ConfigNode) -> str:
    return f"{node.file}:{node.line}: at {node.path}"


def _scalar(value: object, at: ConfigNode) -> ConfigNode:
    return ConfigNode.scalar(value, at)


def _entry(type_name: str, at: ConfigNode, **children: ConfigNode | None) -> ConfigNode:
    """A native observer entry; ``None`` children are left out (the native default applies)."""
    fields = {"type": _scalar(type_name, at)}
    fields.update({k: v for k, v in children.items() if v is not None})
    return ConfigNode.mapping(fields, at)


def _every(group: ConfigNode) -> ConfigNode | None:
    """``main_loop_rate`` (Hz) as the native evaluation interval ``every`` (s)."""
    rate = group.get("main_loop_rate")
    if rate is None:
        return None
    return _scalar(1.0 / rate.float(min=0.0, min_exclusive=True), rate)


def _publishers(callerid: ConfigNode | None, at: ConfigNode) -> ConfigNode:
    """A tug ``callerid`` as a native publisher group; ``[]`` or absent means all publishers."""
    if callerid is None or callerid.is_null:
        return ConfigNode.sequence([], callerid or at)
    items = callerid.list(allow_single=True)
    return ConfigNode.sequence([_scalar(item.str(), item) for item in items], callerid)


def _filter(node: ConfigNode | None) -> ConfigNode | None:
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


def _states(node: ConfigNode | None, quantities: Mapping[str, str],
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


def _acceleration_window(*sources: tuple[ConfigNode, ConfigNode | None]) -> ConfigNode | None:
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


class _Translator:
    def __init__(self) -> None:
        self.entries: list[ConfigNode] = []
        self.warnings: list[str] = []
        self._kinds: dict[str, Callable[[ConfigNode], None]] = {
            "activated": self._activated,
            "hz": self._hz,
            "timeout": self._timeout,
            "scores": self._scores,
            "timestamp": self._timestamp,
            "timing": self._timing,
            "resources": self._resources,
            "velocity": self._velocity,
            "moveing": self._moving,
            "moving": self._moving,
        }

    def group(self, group: ConfigNode) -> None:
        if not group.is_map:
            raise group.error("expected an observer group (a mapping with 'type'), "
                              f"got {'a list' if group.is_list else repr(group.raw)}")
        kind = group["type"]
        if kind.raw == "network":
            raise kind.error("the network observer has no tug_observers form here; "
                             "write the file in the native format (docs/configuration.md)")
        self._kinds[kind.str(choices=self._kinds)](group)

    # ---- topic observers: topics[].callerids[] --------------------------------------------

    def _per_publisher_group(self, group: ConfigNode, native: str, group_keys: Iterable[str],
                             build: Callable[[ConfigNode], dict[str, ConfigNode | None]]) -> None:
        group.check_keys(["type", "main_loop_rate", "topics", *_IGNORED])
        every = _every(group)
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
                self.entries.append(_entry(
                    native, callers, topic=name,
                    publishers=_publishers(_child(callers, "callerid"), callers),
                    every=every, **build(callers)))

    def _hz(self, group: ConfigNode) -> None:
        quantities = {"frequenzy": "period", "frequenz": "period"}
        self._per_publisher_group(group, "hz", ["filter", "states"], lambda c: {
            "filter": _filter(_child(c, "filter")),
            "states": _states(_child(c, "states"), quantities)})

    def _timestamp(self, group: ConfigNode) -> None:
        self._per_publisher_group(group, "timestamp", ["filter", "states"], lambda c: {
            "filter": _filter(_child(c, "filter")),
            "states": _states(_child(c, "states"), {"age": "age"})})

    def _timeout(self, group: ConfigNode) -> None:
        self._per_publisher_group(group, "timeout", ["timeout", "max_timeouts_in_a_row"],
                                  lambda c: {"timeout": c.get("timeout"),
                                             "max_timeouts_in_a_row":
                                                 c.get("max_timeouts_in_a_row")})

    def _scores(self, group: ConfigNode) -> None:
        group.check_keys(["type", "main_loop_rate", "topics", *_IGNORED])
        every = _every(group)
        for topic in group["topics"].list():
            topic.check_keys(["name", "filter", "states"])
            self.entries.append(_entry(
                "scores", topic, topic=topic["name"], every=every,
                filter=_filter(_child(topic, "filter")),
                states=_states(_child(topic, "states"), {"score": "score"})))

    def _timing(self, group: ConfigNode) -> None:
        group.check_keys(["type", "main_loop_rate", "topics", *_IGNORED])
        every = _every(group)
        for pair in group["topics"].list():
            pair.check_keys(["topicA", "calleridA", "topicB", "calleridB", "single_shot_mode",
                             "filter", "states"])
            self.entries.append(_entry(
                "timing", pair, topic_a=pair["topicA"],
                publishers_a=_publishers(_child(pair, "calleridA"), pair),
                topic_b=pair["topicB"],
                publishers_b=_publishers(_child(pair, "calleridB"), pair),
                single_shot=pair.get("single_shot_mode"), every=every,
                filter=_filter(_child(pair, "filter")),
                states=_states(_child(pair, "states"), {"delay": "delay"})))

    # ---- node observers: nodes[] --------------------------------------------------------

    def _activated(self, group: ConfigNode) -> None:
        group.check_keys(["type", "main_loop_rate", "start_up_time", "nodes", *_IGNORED])
        every = _every(group)
        start_up = group.get("start_up_time")
        for node in group["nodes"].list():
            node.check_keys(["name"])
            self.entries.append(_entry("activated", node, node=node["name"],
                                       start_up_time=start_up, every=every))

    def _resources(self, group: ConfigNode) -> None:
        group.check_keys(["type", "main_loop_rate", "nodes", *_IGNORED])
        every = _every(group)
        for node in group["nodes"].list():
            node.check_keys(["name", "cpu_filter", "mem_filter", "states"])
            self.entries.append(_entry(
                "resources", node, node=node["name"], every=every,
                cpu_filter=_filter(_child(node, "cpu_filter")),
                memory_filter=_filter(_child(node, "mem_filter")),
                states=_states(_child(node, "states"), {"cpu": "cpu", "memory": "memory"})))

    # ---- motion observers ---------------------------------------------------------------

    def _velocity(self, group: ConfigNode) -> None:
        group.check_keys(["type", "main_loop_rate", "correlations", *_IGNORED])
        every = _every(group)
        for corr in group["correlations"].list(allow_single=True):
            corr.check_keys(["source_A", "source_B", *(u for u, _ in _ROTATIONS),
                             *_AXIS_FILTERS, "states"])
            source_a, window_a = self._source(corr, "source_A", acceleration=True)
            source_b, window_b = self._source(corr, "source_B", acceleration=True)
            if source_a is None or source_b is None:
                continue
            self.entries.append(_entry(
                "velocity", corr, source_a=source_a, source_b=source_b,
                acceleration_window_size=_acceleration_window(
                    (source_a, window_a), (source_b, window_b)),
                every=every, **self._motion(corr)))

    def _moving(self, group: ConfigNode) -> None:
        group.check_keys(["type", "main_loop_rate", "moveings", "correlations", *_IGNORED])
        every = _every(group)
        found = group.first("moveings", "correlations")
        if found is None:
            raise group.error("missing required key 'moveings'")
        for item in found[1].list(allow_single=True):
            item.check_keys(["source", *(u for u, _ in _ROTATIONS), *_AXIS_FILTERS, "states"])
            source, _ = self._source(item, "source", acceleration=False)
            if source is None:
                continue
            self.entries.append(_entry("moving", item, source=source, every=every,
                                       **self._motion(item)))

    def _motion(self, item: ConfigNode) -> dict[str, ConfigNode | None]:
        """Axis filters and states of a velocity or moving entry.

        A rotation switched off (``use_yaw: false``) stays off, and its filter and state
        checks, which the original tool ignores, are left out.
        """
        dropped = [axis for switch, axis in _ROTATIONS
                   if switch in item and not item[switch].bool()]
        fields: dict[str, ConfigNode | None] = {
            switch: item[switch] for switch, axis in _ROTATIONS if axis in dropped}
        fields.update({f"{axis}_filter": _filter(_child(item, f"{axis}_filter"))
                       for axis in _AXES if axis not in dropped})
        fields["states"] = _states(_child(item, "states"), _MOTION_QUANTITIES, dropped)
        return fields

    def _source(self, item: ConfigNode, key: str, *, acceleration: bool
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
                         "base_frame", "target_frame", *_AXIS_FILTERS,
                         *(["acceleartion_window_size", "acceleration_window_size"]
                           if acceleration else [])])
        kind = node["type"]
        if kind.raw == "tf":
            raise kind.error("tf sources are not supported (the black box observes topics); "
                             "use an odometry, twist or imu topic")
        for axis_filter in _AXIS_FILTERS:
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
