"""Agreement of two motion sources, compared as accelerations (tug ``movement``).

Each source (see :class:`~blackbox.observe.observers.moving.MotionSource`) is turned into
per-axis accelerations: a velocity becomes the least-squares slope of velocity over arrival
time across the last ``acceleration_window_size`` messages (default 10); an imu's linear
acceleration is used as it is. Whenever either source has a new message and both have an
estimate, the per-axis difference ``a_A - a_B`` goes into that axis's filter. States judge
the differences over ``x``, ``y``, ``z``, ``rot_x``, ``rot_y``, ``rot_z`` (a state checks
only the axes it names; ``use_roll``/``use_pitch``/``use_yaw`` switch angular axes off).

Arrival time is used rather than ``header.stamp`` so any source works, stamped or not.
An imu measures gravity on its vertical axis; leave that axis out of the states.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from typing import ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Observation, Resource
from blackbox.observe.base import OBSERVERS, Mode, ObserverKind, Subject
from blackbox.observe.observers.entry import COMMON_KEYS, read_every
from blackbox.observe.observers.moving import (
    AXES,
    AXIS_FILTER_KEYS,
    AXIS_QUANTITIES,
    ROTATION_SWITCHES,
    MotionSource,
    axis_text,
    read_axes,
    read_axis_quantities,
    read_source,
)
from blackbox.observe.observers.quantity import FilteredQuantity, JudgedObserver, SampleProblems
from blackbox.observe.states import StateSpec, parse_states

DEFAULT_ACCELERATION_WINDOW = 10


def regression_slope(times: Sequence[float], values: Sequence[float]) -> float | None:
    """Least-squares slope of ``values`` over ``times``; ``None`` without a time spread."""
    n = len(times)
    if n < 2:
        return None
    t_mean = sum(times) / n
    v_mean = sum(values) / n
    num = 0.0
    den = 0.0
    for t, v in zip(times, values, strict=True):
        dt = t - t_mean
        num += dt * (v - v_mean)
        den += dt * dt
    return num / den if den > 0.0 else None


class AccelerationEstimate:
    """Per-axis accelerations of one motion source over its last ``window`` messages."""

    def __init__(self, source: MotionSource, axes: Sequence[str], window: int) -> None:
        self.source = source
        self.window = window
        self.times: deque[float] = deque(maxlen=window)
        self._axes: list[tuple[int, bool, deque[float]]] = [
            (AXES.index(axis), axis in ("x", "y", "z") and source.linear_is_acceleration,
             deque(maxlen=window)) for axis in axes]
        self.messages = 0

    @property
    def needed(self) -> int:
        """Messages needed before every axis has an estimate."""
        return 1 if all(direct for _, direct, _ in self._axes) else 2

    def add(self, time: float, components: Sequence[float]) -> None:
        if self.times and time <= self.times[-1]:
            return
        self.messages += 1
        self.times.append(time)
        for index, _, values in self._axes:
            values.append(components[index])

    def accelerations(self) -> list[float] | None:
        """One acceleration per observed axis, or ``None`` while any is unknown."""
        if not self.times:
            return None
        out: list[float] = []
        for _, direct, values in self._axes:
            a = regression_slope(self.times, values) if not direct else values[-1]
            if a is None:
                return None
            out.append(a)
        return out


class VelocityObserver(JudgedObserver):
    """Difference of two sources' accelerations, per axis."""

    type_name: ClassVar[str] = "velocity"

    def __init__(self, source_a: MotionSource, source_b: MotionSource,
                 axes: Mapping[str, FilteredQuantity], states: Sequence[StateSpec] = (),
                 acceleration_window_size: int = DEFAULT_ACCELERATION_WINDOW,
                 every: float = 1.0) -> None:
        if acceleration_window_size < 2:
            raise ValueError("acceleration_window_size must be >= 2 (a slope needs two points)")
        super().__init__(Resource(topic=source_a.topic, topic_b=source_b.topic),
                         tuple(axes.values()), states, every)
        self.source_a, self.source_b = source_a, source_b
        self.axes = dict(axes)
        self.acceleration_window_size = acceleration_window_size
        names = tuple(self.axes)
        self._a = AccelerationEstimate(source_a, names, acceleration_window_size)
        self._b = AccelerationEstimate(source_b, names, acceleration_window_size)
        self._updates = [q.update for q in self.axes.values()]
        self._problems = SampleProblems()

    def interest(self) -> Interest:
        return Interest(decoded=frozenset({self.source_a.topic, self.source_b.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        estimates = [e for e in (self._a, self._b) if e.source.topic == msg.topic]
        if not estimates:
            return
        value = self._problems.value_of(msg, msg.topic)
        if value is None:
            return
        for estimate in estimates:
            try:
                components = estimate.source.read(value)
            except ValueError as exc:
                self._problems.add(f"{msg.topic}: {exc}")
                return
            estimate.add(msg.time, components)
        a = self._a.accelerations()
        if a is None:
            return
        b = self._b.accelerations()
        if b is None:
            return
        for update, a_i, b_i in zip(self._updates, a, b, strict=True):
            update(a_i - b_i)

    def evaluate(self, now: float) -> list[Observation]:
        skipped = self._problems.report(now, self.type_name, self.resource)
        if skipped is not None:
            return [skipped]
        summaries = {axis: q.summary() for axis, q in self.axes.items()}
        if any(s is None for s in summaries.values()):
            waiting = ", ".join(f"{e.source.topic} {min(e.messages, e.needed)} of {e.needed}"
                                for e in (self._a, self._b))
            return [self.unavailable(now, f"waiting for messages on both sources ({waiting})")]
        return [self.judged(now, summaries, f"acceleration difference {axis_text(summaries)}")]

    def subject(self) -> str:
        return f"{self.source_a.describe()} vs {self.source_b.describe()}"

    def filtering(self) -> str:
        return (f"acceleration over {self.acceleration_window_size} messages; "
                f"{super().filtering()}")


def velocity_from_config(node: ConfigNode) -> VelocityObserver:
    node.check_keys((*COMMON_KEYS, "source_a", "source_b", "acceleration_window_size",
                     *(s for s, _ in ROTATION_SWITCHES), *AXIS_FILTER_KEYS, "states"))
    axes = read_axes(node)
    window = node.get("acceleration_window_size")
    return VelocityObserver(
        source_a=read_source(node, "source_a"),
        source_b=read_source(node, "source_b"),
        axes=read_axis_quantities(node, axes),
        states=parse_states(node.get("states"), axes),
        acceleration_window_size=(DEFAULT_ACCELERATION_WINDOW if window is None
                                  else window.int(min=2)),
        every=read_every(node),
    )


def velocity_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    group.check_keys(["type", "main_loop_rate", "correlations", *tug.IGNORED])
    every = tug.every(group)
    for corr in group["correlations"].list(allow_single=True):
        corr.check_keys(["source_A", "source_B", *(u for u, _ in tug.ROTATIONS),
                         *tug.AXIS_FILTERS, "states"])
        source_a, window_a = out.source(corr, "source_A", acceleration=True)
        source_b, window_b = out.source(corr, "source_B", acceleration=True)
        if source_a is None or source_b is None:
            continue
        out.entries.append(tug.entry(
            "velocity", corr, source_a=source_a, source_b=source_b,
            acceleration_window_size=tug.acceleration_window(
                (source_a, window_a), (source_b, window_b)),
            every=every, **out.motion(corr)))


OBSERVERS.add("velocity", ObserverKind(
    "velocity", velocity_from_config, Subject.TOPIC_PAIR, AXIS_QUANTITIES, judges=Mode.RIGHT,
    aliases=("movement",), tug=velocity_from_tug, logged_values=6),
    example={"type": "velocity", "source_a": {"type": "twist", "topic": "/cmd_vel"},
             "source_b": {"type": "imu", "topic": "/imu"}, "use_roll": False, "use_pitch": False,
             "x_filter": {"type": "median", "window_size": 5},
             "states": [{"number": 1, "name": "agree",
                         "x": {"value": {"type": "in_between", "lower_bound": -0.5,
                                         "upper_bound": 0.5}}}]})
