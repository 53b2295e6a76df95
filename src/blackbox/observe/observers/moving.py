"""Whether the robot moves: per-axis motion of one source through per-axis filters.

A source is a topic of type ``odometry`` (nav_msgs/Odometry: ``twist.twist.linear`` and
``.angular``), ``twist`` (geometry_msgs/Twist, or TwistStamped with the same under
``twist``) or ``imu`` (sensor_msgs/Imu: ``linear_acceleration`` and ``angular_velocity``,
taken as they are). The axes are ``x``, ``y``, ``z`` (linear) and ``rot_x``, ``rot_y``,
``rot_z`` (angular); ``use_roll``, ``use_pitch`` and ``use_yaw`` (default true) switch the
angular ones on or off. States (for example ``idle``: every axis near 0, ``moving``) tell
what the robot does; the observation names the fitting states.

This module also holds what the ``velocity`` observer shares: reading motion sources.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Observation, Resource
from blackbox.observe.base import OBSERVERS, Mode, ObserverKind, Quantity, Subject
from blackbox.observe.fieldpath import compile_field_path
from blackbox.observe.observers.entry import (
    COMMON_KEYS,
    read_bool,
    read_every,
    read_name,
    read_quantity,
)
from blackbox.observe.observers.quantity import (
    FilteredQuantity,
    JudgedObserver,
    SampleProblems,
    number,
)
from blackbox.observe.states import StateSpec, parse_states

AXES: tuple[str, ...] = ("x", "y", "z", "rot_x", "rot_y", "rot_z")
ROTATION_SWITCHES: tuple[tuple[str, str], ...] = (
    ("use_roll", "rot_x"), ("use_pitch", "rot_y"), ("use_yaw", "rot_z"))
AXIS_FILTER_KEYS: tuple[str, ...] = tuple(f"{axis}_filter" for axis in AXES)
SOURCE_TYPES: tuple[str, ...] = ("odometry", "twist", "imu")

_Reader = Callable[[Any], float]


def _readers(linear: str, angular: str) -> tuple[_Reader, ...]:
    return tuple(compile_field_path(f"{prefix}.{c}")
                 for prefix in (linear, angular) for c in ("x", "y", "z"))


_ODOMETRY = _readers("twist.twist.linear", "twist.twist.angular")
_TWIST = _readers("linear", "angular")
_TWIST_STAMPED = _readers("twist.linear", "twist.angular")
_IMU = _readers("linear_acceleration", "angular_velocity")


def _has(value: Any, name: str) -> bool:
    return name in value if isinstance(value, Mapping) else hasattr(value, name)


@dataclass(frozen=True, slots=True)
class MotionSource:
    """A topic carrying motion, and what kind of message it is."""

    kind: str
    topic: str

    @property
    def linear_is_acceleration(self) -> bool:
        return self.kind == "imu"

    def read(self, value: Any) -> tuple[float, ...]:
        """``(x, y, z, rot_x, rot_y, rot_z)`` of one decoded message.

        Raises ValueError when a component is missing, not a number or not finite.
        """
        if self.kind == "odometry":
            readers = _ODOMETRY
        elif self.kind == "imu":
            readers = _IMU
        else:
            readers = _TWIST_STAMPED if _has(value, "twist") else _TWIST
        components = tuple(read(value) for read in readers)
        for axis, x in zip(AXES, components, strict=True):
            if not math.isfinite(x):
                raise ValueError(f"{axis} is {x}, not a finite number")
        return components

    def describe(self) -> str:
        return f"{self.kind} {self.topic}"


def read_source(node: ConfigNode, key: str) -> MotionSource:
    """A source mapping ``{type: odometry|twist|imu, topic: /name}``."""
    child = node[key]
    if not child.is_map:
        raise child.error(f"{key} must be a mapping like {{type: odometry, topic: /odom}}")
    child.check_keys(("type", "topic"))
    return MotionSource(child["type"].str(SOURCE_TYPES), read_name(child, "topic"))


def read_axes(node: ConfigNode) -> tuple[str, ...]:
    """The observed axes: linear always, angular unless switched off."""
    off = {axis for switch, axis in ROTATION_SWITCHES if not read_bool(node, switch, True)}
    return tuple(axis for axis in AXES if axis not in off)


def read_axis_quantities(node: ConfigNode, axes: Sequence[str]) -> dict[str, FilteredQuantity]:
    """One filtered quantity per observed axis; a switched-off axis may not be configured."""
    switch_of = {axis: switch for switch, axis in ROTATION_SWITCHES}
    off = [axis for axis in AXES if axis not in axes]
    states = node.get("states")
    entries = [e for e in states.list() if e.is_map] if states is not None else []
    for axis in off:
        used = node.get(f"{axis}_filter")
        used = used if used is not None else next(
            (e[axis] for e in entries if axis in e), None)
        if used is not None:
            raise used.error(f"{used.path.rsplit('.', 1)[-1]} given but {axis} is switched "
                             f"off ({switch_of[axis]}: false)")
    return {axis: read_quantity(node, f"{axis}_filter", axis) for axis in axes}


def axis_text(summaries: Mapping[str, Any]) -> str:
    return ", ".join(f"{axis} {number(s.value)}" for axis, s in summaries.items()
                     if s is not None)


AXIS_QUANTITIES: tuple[Quantity, ...] = tuple(Quantity(axis) for axis in AXES)
"""The quantities of a motion observer: one per axis, without a unit (a speed for
odometry and twist, an acceleration for imu)."""


class MovingObserver(JudgedObserver):
    """Per-axis motion of one source, for telling moving from idle."""

    type_name: ClassVar[str] = "moving"

    def __init__(self, source: MotionSource, axes: Mapping[str, FilteredQuantity],
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        super().__init__(Resource(topic=source.topic), tuple(axes.values()), states, every)
        self.source = source
        self.axes = dict(axes)
        self._feeds = [(AXES.index(axis), q.update) for axis, q in self.axes.items()]
        self._problems = SampleProblems()

    def interest(self) -> Interest:
        return Interest(decoded=frozenset({self.source.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        value = self._problems.value_of(msg)
        if value is None:
            return
        try:
            components = self.source.read(value)
        except ValueError as exc:
            self._problems.add(str(exc))
            return
        for index, update in self._feeds:
            update(components[index])

    def evaluate(self, now: float) -> list[Observation]:
        skipped = self._problems.report(now, self.type_name, self.resource)
        if skipped is not None:
            return [skipped]
        summaries = {axis: q.summary() for axis, q in self.axes.items()}
        if any(s is None for s in summaries.values()):
            return [self.unavailable(now, "waiting for first message")]
        return [self.judged(now, summaries, axis_text(summaries))]

    def subject(self) -> str:
        return self.source.describe()


def moving_from_config(node: ConfigNode) -> MovingObserver:
    node.check_keys((*COMMON_KEYS, "source", *(s for s, _ in ROTATION_SWITCHES),
                     *AXIS_FILTER_KEYS, "states"))
    axes = read_axes(node)
    return MovingObserver(
        source=read_source(node, "source"),
        axes=read_axis_quantities(node, axes),
        states=parse_states(node.get("states"), axes),
        every=read_every(node),
    )


def moving_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    group.check_keys(["type", "main_loop_rate", "moveings", "correlations", *tug.IGNORED])
    every = tug.every(group)
    found = group.first("moveings", "correlations")
    if found is None:
        raise group.error("missing required key 'moveings'")
    for item in found[1].list(allow_single=True):
        item.check_keys(["source", *(u for u, _ in tug.ROTATIONS), *tug.AXIS_FILTERS, "states"])
        source, _ = out.source(item, "source", acceleration=False)
        if source is None:
            continue
        out.entries.append(tug.entry("moving", item, source=source, every=every,
                                     **out.motion(item)))


OBSERVERS.add("moving", ObserverKind(
    "moving", moving_from_config, Subject.TOPIC, AXIS_QUANTITIES, judges=Mode.RIGHT,
    tug=moving_from_tug, tug_names=("moving", "moveing"), logged_values=6),
    example={"type": "moving", "source": {"type": "odometry", "topic": "/odom"},
             "x_filter": {"type": "mean", "window_size": 3},
             "states": [{"number": 1, "name": "still",
                         "x": {"value": {"type": "in_between", "lower_bound": -0.1,
                                         "upper_bound": 0.1}}}]})
