"""One numeric signal of a topic, sampled on a regular grid, and a two-sided CUSUM.

Learned relations (``relation``) and per-signal liveness (``liveness``) read single numbers
out of messages: a scalar field (``twist.twist.linear.x``) or one element of a numeric
array (``velocity[1]``). Topics arrive at different rates and at irregular times, so a
relation compares them on a common grid of ``step`` seconds. The grid value of a signal at
``tau`` is the mean, over the cell ``[tau - step/2, tau + step/2]``, of the straight lines
joining its samples (:func:`window_mean`): a fast signal is averaged over the cell, a slow
one interpolated, and neither is shifted in time by where its samples happen to fall (a
cell mean or a held value would delay a signal by up to one period, differently in every
run, and a relation with a large gain would see that as a residual). The cell is judged
``delay`` seconds late, when the sample after it has arrived. A line between samples more
than ``fresh`` seconds apart is a gap: the signal is *stale* and the grid value is NaN (no
verdict is made on it).

Everything is pure: time is passed in, nothing reads a clock.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass
from numbers import Real
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from blackbox.config.node import ConfigNode
from blackbox.observe.fieldpath import compile_field_access

if TYPE_CHECKING:
    from blackbox.events import MessageArrival

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class SignalRef:
    """A number in the messages of a topic: ``field`` is a path (``ranges[3]`` allowed)."""

    topic: str
    field: str

    def label(self) -> str:
        return f"{self.topic} {self.field}"


def read_signal_ref(node: ConfigNode) -> SignalRef:
    """``{topic: /odom, field: twist.twist.linear.x}``."""
    node.check_keys(("topic", "field"))
    field_node = node["field"]
    path = field_node.str()
    try:
        compile_field_access(path)
    except ValueError as exc:
        raise field_node.error(str(exc)) from None
    topic = node["topic"].str()
    if not topic.strip():
        raise node["topic"].error("topic must be a name")
    return SignalRef(topic, path)


def number_of(value: Any) -> float | None:
    """``value`` as a float, ``None`` when it is not a real number (bools are not)."""
    kind = type(value)
    if kind is float:
        return value  # type: ignore[no-any-return]
    if kind is int:
        return float(value)
    if kind is bool:
        return None
    if isinstance(value, Real):
        return float(value)
    if getattr(value, "ndim", None) == 0 and getattr(value, "dtype", None) is not None \
            and value.dtype.kind in "iuf":
        return float(value)
    return None


STAMP_LIMIT = 1.0
"""Seconds a header stamp may lie from its message's arrival and still time the sample."""


def sample_time(arrival: float, stamp: float | None) -> float:
    """When a sample was measured: its header stamp when it has one within ``STAMP_LIMIT``
    of its arrival, else its arrival. A driver stamps at acquisition; the arrival adds
    the publisher's and the transport's lateness, which under load moved the real ROS 1
    diffdrive robot's samples by tens of milliseconds, a turning robot's yaw rate by
    several noise std (a relation between two such signals failed 54 times an hour).
    A stamp of zero, of another clock or far off is no measurement time."""
    if stamp is None or stamp == 0.0 or abs(arrival - stamp) > STAMP_LIMIT:
        return arrival
    return stamp


class SignalReader:
    """Reads one signal from decoded messages; counts what could not be read, and why."""

    __slots__ = ("_access", "_key", "last_problem", "non_finite", "ref", "unreadable")

    def __init__(self, ref: SignalRef) -> None:
        self.ref = ref
        self._access: Callable[[Any], Any] = compile_field_access(ref.field)
        self._key = ("number", ref.field)
        self.unreadable = 0
        self.non_finite = 0
        self.last_problem = ""

    def read(self, message: Any) -> float | None:
        """The finite number at the field, or ``None`` (counted) when there is none."""
        return self._counted(self._number(message))

    def read_arrival(self, arrival: MessageArrival, message: Any) -> float | None:
        """:meth:`read` of ``arrival``'s decoded ``message``, shared through its memo with
        every other reader of the same field."""
        memo = arrival.memo
        found = memo.get(self._key)
        if found is None:
            found = memo[self._key] = self._number(message)
        if type(found) is float and found - found == 0.0:  # finite: the common case
            return found
        return self._counted(found)

    def _number(self, message: Any) -> float | str:
        """The number at the field, or why there is none."""
        try:
            x = number_of(self._access(message))
        except ValueError as exc:
            return str(exc)
        if x is None:
            return f"{self.ref.field} is not a number"
        return x

    def _counted(self, found: float | str) -> float | None:
        if isinstance(found, str):
            self.unreadable += 1
            self.last_problem = found
            return None
        if not math.isfinite(found):
            self.non_finite += 1
            self.last_problem = f"{self.ref.field} is {found}"
            return None
        return found


class GridCell:
    """The grid value of one signal (module docstring): the recent samples with the running
    integral of the line through them, so a cell mean is two binary searches."""

    __slots__ = ("_c", "_head", "_t", "_x", "delay", "fresh", "half", "step")

    def __init__(self, fresh: float, step: float, delay: float) -> None:
        self.fresh = fresh
        self.step = step
        self.half = step / 2.0
        self.delay = delay
        self._t: list[float] = []
        self._x: list[float] = []
        self._c: list[float] = []
        """Times (strictly increasing), values and the integral from the first sample."""
        self._head = 0

    @property
    def samples(self) -> list[tuple[float, float]]:
        """The samples still needed, oldest first."""
        h = self._head
        return list(zip(self._t[h:], self._x[h:], strict=True))

    @property
    def last_time(self) -> float:
        return self._t[-1] if self._t else -math.inf

    @property
    def first_time(self) -> float:
        """The oldest sample kept (``inf`` when empty)."""
        return self._t[0] if self._t else math.inf

    def add(self, t: float, x: float) -> None:
        """A sample; one not later than the last is dropped (the line needs increasing
        times, and learning drops the same ones)."""
        times = self._t
        if not times:
            times.append(t)
            self._x.append(x)
            self._c.append(0.0)
            return
        t0 = times[-1]
        if t <= t0:
            return
        times.append(t)
        self._c.append(self._c[-1] + (t - t0) * (x + self._x[-1]) * 0.5)
        self._x.append(x)

    def _integral(self, u: float) -> float:
        """The integral of the line up to ``u``, NaN in a gap or beyond the samples."""
        times = self._t
        i = bisect_right(times, u, self._head) - 1
        if i < self._head or i >= len(times) - 1:
            return math.nan
        ta, tb = times[i], times[i + 1]
        if tb - ta > self.fresh:
            return math.nan
        xa = self._x[i]
        xu = xa + (u - ta) / (tb - ta) * (self._x[i + 1] - xa)
        return self._c[i] + (u - ta) * (xa + xu) * 0.5

    def close(self, g: float) -> float:
        """The value at ``g - delay`` (the grid point the relation judges at tick ``g``)."""
        tau = g - self.delay
        lo = tau - self.half
        times = self._t
        keep = bisect_right(times, lo, self._head) - 1
        if keep > self._head:
            self._head = keep
            if keep > 512:
                del times[:keep], self._x[:keep], self._c[:keep]
                self._head = 0
        return (self._integral(tau + self.half) - self._integral(lo)) / self.step

    def reset(self) -> None:
        self._t.clear()
        self._x.clear()
        self._c.clear()
        self._head = 0


class SharedGridCell(GridCell):
    """A grid cell that several relation observers read (:func:`share_cells`): each grid
    point is closed once, by whichever observer reaches it first, and the others read the
    value it closed. One observer feeds it the samples."""

    __slots__ = ("_closed",)

    KEEP = 256
    """Closed grid points kept for observers that reach them later (12.8 s of a 0.05 s
    grid; an observer is at most an evaluation interval behind another)."""

    def __init__(self, fresh: float, step: float, delay: float) -> None:
        super().__init__(fresh, step, delay)
        self._closed: dict[int, float] = {}

    def close(self, g: float) -> float:
        k = round(g / self.step)  # grids of different observers differ in rounding only
        x = self._closed.get(k)
        if x is None:
            x = self._closed[k] = super().close(g)
            if len(self._closed) > self.KEEP:
                del self._closed[next(iter(self._closed))]
        return x

    def reset(self) -> None:
        super().reset()
        self._closed.clear()


@dataclass(frozen=True, slots=True)
class GridKey:
    """What makes a signal's grid cell: two signals with equal keys have equal cells."""

    signal: SignalRef
    stamp: str | None
    fresh: float
    step: float
    delay: float


@runtime_checkable
class GridUser(Protocol):
    """An observer that puts signals on a grid of cells (``relation``)."""

    def grid_keys(self) -> Mapping[SignalRef, GridKey]:
        """Per signal, the key of its cell."""
        ...

    def use_cells(self, cells: Mapping[SignalRef, GridCell], fed: Collection[SignalRef]
                  ) -> None:
        """Read these cells (shared with other observers) and feed only those in ``fed``."""
        ...


def share_cells(users: Iterable[GridUser]) -> int:
    """Give the observers that put one signal on equal grids one cell: the signal is read
    and its grid points closed once, not once per relation (a learned robot of ten
    redundant signals has each in five relations). The first observer feeds it. Returns
    how many cells are shared."""
    users = list(users)
    groups: dict[GridKey, list[tuple[GridUser, SignalRef]]] = {}
    for user in users:
        for ref, key in user.grid_keys().items():
            groups.setdefault(key, []).append((user, ref))
    cells: dict[int, dict[SignalRef, GridCell]] = {id(u): {} for u in users}
    fed: dict[int, list[SignalRef]] = {id(u): [] for u in users}
    shared = 0
    for key, group in groups.items():
        if len(group) < 2:
            continue
        shared += 1
        cell = SharedGridCell(key.fresh, key.step, key.delay)
        for user, ref in group:
            cells[id(user)][ref] = cell
        first, ref = group[0]
        fed[id(first)].append(ref)
    for user in users:
        if cells[id(user)]:
            user.use_cells(cells[id(user)], fed[id(user)])
    return shared


def wrapped_difference(a: float, b: float) -> float:
    """``a - b`` for angles: the shortest way round, in ``(-pi, pi]``."""
    d = math.fmod(a - b, TWO_PI)
    if d > math.pi:
        d -= TWO_PI
    elif d <= -math.pi:
        d += TWO_PI
    return d


@dataclass(frozen=True, slots=True)
class CusumSpec:
    """Page's CUSUM on standardised block statistics: drift ``k`` (half the shift it is
    tuned for, in noise units), alarm at ``h``. ``h`` is calibrated while learning for a
    stated false-alarm rate (docs/learn.md)."""

    k: float
    h: float

    @classmethod
    def read(cls, node: ConfigNode) -> CusumSpec:
        node.check_keys(("k", "h"))
        return cls(node["k"].float(min=0.0), node["h"].float(min=0.0, min_exclusive=True))


RECOVER_Z = 2.0
"""A block within this many noise std of healthy (``|z|``; upward only for a one-sided
CUSUM) counts towards the end of an alarm."""
CALM_SIDE = 1.0
"""A block counts towards recovery only if its evidence for the alarmed side is below
``CALM_SIDE * k`` (it lowers that side), so a fault still there keeps its alarm."""


class Cusum:
    """Two-sided (or upward only) CUSUM with a ceiling and a recovery test, so an alarm ends
    soon after the fault.

    The statistic stays at most ``ceiling`` drifts above ``h`` and falls by ``k`` per
    healthy block (half a drift: the alarm ends with the first healthy block; a longer
    afterglow was measured to blame neighbours of a fault that had already ended, and an
    alarm outliving its fault by more than the 2 s grace counts as a false alarm).

    Falling by ``k`` a block is a random walk around ``h`` once the fault is gone: a healthy
    block below ``-k`` pushes it back over, and a residual left a little off by the fault's
    end (a relation fitted on another operating mode, a tracked bias) keeps it there for
    seconds (issue 22: most of the false-alarm episodes of a fault campaign on
    `sim:diffdrive` were such afterglows naming a neighbour of a fault that had ended). So
    once in alarm (reached ``h``, not yet back under ``h / 2``), one block that looks
    healthy (``|z| <`` :data:`RECOVER_Z`) and argues against the alarm (it lowers the
    alarmed side: evidence below ``k``) lowers both sides to ``h / 2``: undecided, neither
    accusing nor clearing, and a fault still there needs another ``h / 2`` of evidence to
    alarm again. A fault that is still there keeps its alarm (its blocks keep adding to the
    alarmed side), and the time to the first alarm, which the calibration of ``h`` is
    about, is Page's.
    """

    __slots__ = ("alarmed", "down", "spec", "top", "two_sided", "up")

    def __init__(self, spec: CusumSpec, two_sided: bool = True, ceiling: float = 0.5) -> None:
        self.spec = spec
        self.two_sided = two_sided
        self.top = spec.h + ceiling * max(spec.k, 0.25)
        self.up = 0.0
        self.down = 0.0
        self.alarmed = False

    def calm(self, z: float) -> bool:
        """Whether a block of ``z`` looks healthy and argues against the alarmed side (the
        recovery test below)."""
        side = z if self.up >= self.down else -z  # the evidence for the alarmed side
        return side < CALM_SIDE * self.spec.k and (abs(z) if self.two_sided else z) < RECOVER_Z

    def update(self, z: float) -> float:
        k, top, h = self.spec.k, self.top, self.spec.h
        calm = self.calm(z)
        was_alarmed = self.alarmed
        self.up = min(top, max(0.0, self.up + z - k))
        if self.two_sided:
            self.down = min(top, max(0.0, self.down - z - k))
        stat = self.statistic
        if was_alarmed and calm:  # the block that raised the alarm is no recovery
            self.up = min(self.up, h / 2)
            self.down = min(self.down, h / 2)
            self.alarmed = False
            return self.statistic
        if stat >= h:
            self.alarmed = True
        elif stat < h / 2:
            self.alarmed = False
        return stat

    @property
    def statistic(self) -> float:
        return max(self.up, self.down)

    @property
    def alarm(self) -> bool:
        return self.statistic >= self.spec.h

    def doubt(self) -> None:
        """Both sides down to at most ``h / 2``: undecided (what recovery does), for an
        alarm its observer can no longer judge."""
        self.up = min(self.up, self.spec.h / 2)
        self.down = min(self.down, self.spec.h / 2)
        self.alarmed = False

    def reset(self) -> None:
        self.up = 0.0
        self.down = 0.0
        self.alarmed = False
