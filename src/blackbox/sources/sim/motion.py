"""Shared motion of a simulated robot: latent signals several sensors measure at once.

A differential-drive robot's commanded velocity, wheel odometry and IMU yaw rate all follow
the same motion, so they are correlated; a fault in one sensor breaks that. A topic's
numeric value follows motion signals with a gain each (``follows:`` in docs/simulator.md).

A motion signal is one of

- a *wave*: a mean plus a sum of sines, deterministic in time, optionally scaled per
  operating mode (standing still scales speed to 0, turning scales yaw rate up);
- a *load*: a mean plus gains times the absolute values of other signals (a motor current
  that grows with speed in either direction);
- an *integral* of other signals, optionally leaky with time constant ``tau`` (charge drawn
  from a battery, an odometer, a motor warming towards the temperature its load sustains).

The description (:class:`MotionSignal`, :class:`ModePlan`) lives in the topology; the
values of one run come from a :class:`Motion`, which draws the mode schedule from the run's
seed (unless the plan fixes one) and integrates on a fixed grid, so the same seed gives the
same motion bit for bit.
"""

from __future__ import annotations

import bisect
import math
import random
from collections.abc import Mapping
from dataclasses import dataclass, field

from blackbox.config.node import ConfigNode

INTEGRAL_STEP = 0.05
"""Seconds between the grid points integrals are computed on (trapezoid rule)."""


@dataclass(frozen=True, slots=True)
class Sine:
    amplitude: float
    period: float
    phase: float = 0.0


@dataclass(frozen=True, slots=True)
class MotionSignal:
    """One latent signal; see the module docstring for the three kinds.

    A wave is ``scale(mode) * (mean + sum(amplitude * sin(2 pi t / period + phase)))``,
    ``modes`` mapping a mode name to its scale (a mode not listed scales by 1). A load is
    ``mean + sum(gain * |signal|)`` over ``load``. An integral is ``mean + x`` with
    ``x(0) = 0`` and ``dx/dt = sum(gain * signal) - x / tau`` over ``integral``.
    """

    name: str
    mean: float = 0.0
    terms: tuple[Sine, ...] = ()
    modes: Mapping[str, float] = field(default_factory=dict)
    load: tuple[tuple[str, float], ...] = ()
    integral: tuple[tuple[str, float], ...] = ()
    tau: float | None = None

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(s for s, _ in self.load + self.integral)

    def at(self, t: float) -> float:
        """The wave at ``t`` without modes (scale 1)."""
        value = self.mean
        for s in self.terms:
            value += s.amplitude * math.sin(2.0 * math.pi * t / s.period + s.phase)
        return value


@dataclass(frozen=True, slots=True)
class ModeSpec:
    name: str
    shortest: float
    longest: float


@dataclass(frozen=True, slots=True)
class ModePlan:
    """Operating modes the robot switches between: the first listed starts, each lasts a
    uniform random time in its range, the next is drawn among the others; ``ramp`` seconds
    blend one mode's scales into the next (speeds do not jump). ``seed`` ``None``: the
    schedule is drawn from the run's seed, so different runs drive differently."""

    modes: tuple[ModeSpec, ...]
    ramp: float = 1.0
    seed: int | None = None


class ModeSchedule:
    """The sequence of modes of one run, drawn lazily as far as it is asked for."""

    def __init__(self, plan: ModePlan, seed: int) -> None:
        self.plan = plan
        drawn_from = plan.seed if plan.seed is not None else seed
        self._rng = random.Random(f"blackbox-sim-modes:{drawn_from}")
        self._starts: list[float] = [0.0]
        self._names: list[str] = [plan.modes[0].name]
        self._end = self._draw_length(plan.modes[0])
        self._last = 0

    def _draw_length(self, spec: ModeSpec) -> float:
        return self._rng.uniform(spec.shortest, spec.longest)

    def _extend(self, t: float) -> None:
        by_name = {m.name: m for m in self.plan.modes}
        while self._end <= t:
            others = [m for m in self.plan.modes if m.name != self._names[-1]] or [
                by_name[self._names[-1]]]
            spec = self._rng.choice(others)
            self._starts.append(self._end)
            self._names.append(spec.name)
            self._end += self._draw_length(spec)

    def mode_at(self, t: float) -> str:
        """The mode in force at ``t`` (the new one from the start of its ramp)."""
        t = max(t, 0.0)
        self._extend(t)
        return self._names[bisect.bisect_right(self._starts, t) - 1]

    def segments(self, until: float) -> list[tuple[float, str]]:
        """``(start, mode)`` of every segment starting before ``until``."""
        self._extend(until)
        return [(s, n) for s, n in zip(self._starts, self._names, strict=True) if s < until]

    def _segment(self, t: float) -> int:
        # Queries come nearly in time order: the last segment usually still holds.
        k = self._last
        starts = self._starts
        if starts[k] <= t and ((k + 1 == len(starts) and t < self._end)
                               or (k + 1 < len(starts) and t < starts[k + 1])):
            return k
        self._extend(t)
        k = self._last = bisect.bisect_right(starts, t) - 1
        return k

    def scale(self, signal: MotionSignal, t: float) -> float:
        if not signal.modes:
            return 1.0
        t = max(t, 0.0)
        k = self._segment(t)
        now = signal.modes.get(self._names[k], 1.0)
        since = t - self._starts[k]
        if k == 0 or since >= self.plan.ramp:
            return now
        before = signal.modes.get(self._names[k - 1], 1.0)
        blend = since / self.plan.ramp
        return before + (now - before) * blend


class Motion:
    """The motion signals of one run: ``at(name, t)`` for ``t`` seconds after the start."""

    def __init__(self, signals: Mapping[str, MotionSignal], plan: ModePlan | None,
                 seed: int) -> None:
        self.signals = signals
        self.schedule = ModeSchedule(plan, seed) if plan is not None else None
        self._grids: dict[str, list[float]] = {}
        self._memo: dict[str, tuple[float, float]] = {}

    def at(self, name: str, t: float) -> float:
        if t < 0.0:
            t = 0.0
        # The fields of one message ask for the same signals at the same time.
        memo = self._memo.get(name)
        if memo is not None and memo[0] == t:
            return memo[1]
        value = self._compute(name, t)
        self._memo[name] = (t, value)
        return value

    def _compute(self, name: str, t: float) -> float:
        signal = self.signals[name]
        if signal.integral:
            return signal.mean + self._integral(signal, t)
        if signal.load:
            value = signal.mean
            for source, gain in signal.load:
                value += gain * abs(self.at(source, t))
            return value
        if self.schedule is None or not signal.modes:
            return signal.at(t)
        return self.schedule.scale(signal, t) * signal.at(t)

    def _integral(self, signal: MotionSignal, t: float) -> float:
        grid = self._grids.setdefault(signal.name, [0.0])
        k = int(t / INTEGRAL_STEP)
        while len(grid) <= k + 1:
            i = len(grid) - 1
            a, b = i * INTEGRAL_STEP, (i + 1) * INTEGRAL_STEP
            rate_a = sum(g * self.at(s, a) for s, g in signal.integral)
            rate_b = sum(g * self.at(s, b) for s, g in signal.integral)
            x = grid[i] + 0.5 * (rate_a + rate_b) * INTEGRAL_STEP
            if signal.tau is not None:
                x -= 0.5 * (grid[i] + x) * INTEGRAL_STEP / signal.tau
            grid.append(x)
        frac = t / INTEGRAL_STEP - k
        return grid[k] + (grid[k + 1] - grid[k]) * frac


def motion_from_config(node: ConfigNode) -> dict[str, MotionSignal]:
    """``motion: {v: {mean: 0.3, sines: [{amplitude: 0.4, period: 23}]}, ...}``."""
    out: dict[str, MotionSignal] = {}
    for name, item in node.items():
        item.check_keys(["mean", "sines", "modes", "load", "integral", "tau"])
        kinds = [k for k in ("sines", "load", "integral") if item.get(k) is not None]
        if len(kinds) > 1:
            raise item.error(f"a motion signal is a wave (sines), a load or an integral, "
                             f"not {' and '.join(kinds)}")
        terms: list[Sine] = []
        sines = item.get("sines")
        for s in sines.list() if sines is not None else []:
            s.check_keys(["amplitude", "period", "phase"])
            terms.append(Sine(s["amplitude"].float(),
                              s["period"].float(min=0.0, min_exclusive=True),
                              s["phase"].float() if s.get("phase") is not None else 0.0))
        mean = item["mean"].float() if item.get("mean") is not None else 0.0
        modes: dict[str, float] = {}
        if item.get("modes") is not None:
            if kinds and kinds[0] != "sines":
                raise item["modes"].error("only a wave (mean and sines) is scaled by modes")
            modes = {k: v.float() for k, v in item["modes"].items()}
        load = _gains(item.get("load"))
        integral = _gains(item.get("integral"))
        tau = None
        if item.get("tau") is not None:
            if not integral:
                raise item["tau"].error("tau (a leak time constant) needs integral:")
            tau = item["tau"].float(min=0.0, min_exclusive=True)
        out[name] = MotionSignal(name, mean, tuple(terms), modes, load, integral, tau)
    for name, signal in out.items():
        for source in signal.inputs:
            if source not in out:
                where = node[name]["load" if signal.load else "integral"]
                raise where.error(f"unknown motion signal {source!r}")
    _check_acyclic(out, node)
    return out


def _gains(node: ConfigNode | None) -> tuple[tuple[str, float], ...]:
    if node is None:
        return ()
    return tuple((k, v.float()) for k, v in node.items())


def _check_acyclic(signals: Mapping[str, MotionSignal], node: ConfigNode) -> None:
    done: set[str] = set()

    def visit(name: str, path: tuple[str, ...]) -> None:
        if name in path:
            raise node[path[0]].error(
                f"motion signals depend on each other in a cycle: {' -> '.join((*path, name))}")
        if name in done:
            return
        for source in signals[name].inputs:
            visit(source, (*path, name))
        done.add(name)

    for name in signals:
        visit(name, ())


def modes_from_config(node: ConfigNode, signals: Mapping[str, MotionSignal]) -> ModePlan:
    """``modes: {seed: 1, ramp: 1.0, plan: [{name: stand, duration: [5, 20]}, ...]}``."""
    node.check_keys(["seed", "ramp", "plan"])
    specs: list[ModeSpec] = []
    for item in node["plan"].list():
        item.check_keys(["name", "duration"])
        pair = item["duration"].list()
        if len(pair) != 2:
            raise item["duration"].error("expected [shortest, longest] in seconds")
        lo = pair[0].float(min=0.0, min_exclusive=True)
        hi = pair[1].float(min=lo)
        name = item["name"].str()
        if any(s.name == name for s in specs):
            raise item["name"].error(f"mode {name} is listed twice")
        specs.append(ModeSpec(name, lo, hi))
    if not specs:
        raise node["plan"].error("list at least one mode")
    known = {s.name for s in specs}
    for name, signal in signals.items():
        for mode in signal.modes:
            if mode not in known:
                raise node.error(f"motion signal {name} scales unknown mode {mode!r}; "
                                 f"modes: {', '.join(sorted(known))}")
    ramp = node["ramp"].float(min=0.0) if node.get("ramp") is not None else 1.0
    seed = node["seed"].int() if node.get("seed") is not None else None
    return ModePlan(tuple(specs), ramp, seed)
