"""Is a signal alive? A stuck value and a noise burst are faults even inside the envelope.

A healthy sensor's reading moves a little from one message to the next (noise, motion).
``blackbox learn`` measures, per numeric signal of a topic, how it moves:

* **repeats**: the longest run of exactly equal consecutive samples while healthy; a run of
  ``repeats`` equal samples (at least twice the healthy one) is a *stuck* value. A signal
  that repeated a lot while healthy (quantised, a command held constant) gets no such check;
* **noise**: per block of ``block`` samples, ``ln(mean squared second difference)`` of
  consecutive samples (``x[k] - 2 x[k-1] + x[k-2]``: smooth motion cancels, noise stays),
  standardised by its healthy ``mean`` and ``std``; an upward CUSUM (``k``, ``h``
  calibrated for a stated false-alarm rate) finds a *noise burst*. Each squared second
  difference counts at most ``cap`` (learned as a multiple of the healthy mean): a step
  (an offset or scale fault ending, the value going back) is one large first difference,
  two large second differences, and without the cap those two alone lifted a block by
  ten standard deviations and raised a burst seconds after the fault had ended; a noise
  burst is many large differences and still lifts every block. Only upward: a signal
  moves less when the robot stands still, so a variance collapse is no fault by itself
  (a frozen value is caught by ``repeats`` and by the relations);
* **rate** (signals that climb: a wheel angle, an odometer, a warming motor): the change
  between consecutive samples per second (the time between them at least ``period``:
  arrivals in bursts share a receive time) above ``at_most`` is a *step*, a fault: such a
  signal is an integral of something (distance, heat) and moves smoothly. It fails the
  evaluation after the step.

Angles (``wrap: true``) take differences the short way round, so a heading crossing +-pi is
not a jump. A topic silent for longer than ``fresh`` (a node killed and started again, a
stalled publisher) starts its differences, blocks and equal-sample runs afresh when it
resumes: the first difference across the gap is the motion of the silent seconds, not noise
(on the real diffdrive robots it raised a noise burst one to three seconds after every
restarted node, three false alarms in a 900 s ROS 1 campaign).

A failed ``liveness`` accuses the topic's producers; a passing one clears nobody (it cannot
see an offset), so its type does not exonerate.

.. code-block:: yaml

    - type: liveness
      topic: /imu/data
      fresh: 0.5
      signals:
        - {name: angular_velocity_z, field: angular_velocity.z, repeats: 5,
           noise: {block: 10, mean: -7.8, std: 0.45, cap: 0.0103,
                   cusum: {k: 0.5, h: 12.1}}}
    - type: liveness
      topic: /odometer
      fresh: 6.0
      signals:
        - {name: data, field: data, rate: {at_most: 192.0, period: 1.0}}
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import OBSERVERS, Mode, ObserverBase, ObserverKind, Subject
from blackbox.observe.observers.entry import COMMON_KEYS, read_every, read_name
from blackbox.observe.signals import (
    Cusum,
    CusumSpec,
    SignalReader,
    SignalRef,
    read_signal_ref,
    wrapped_difference,
)

_NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")
TINY = 1e-300
"""Added to a block's mean squared difference so an exactly frozen block has a logarithm."""


@dataclass(frozen=True, slots=True)
class NoiseSpec:
    block: int
    mean: float
    std: float
    cusum: CusumSpec
    cap: float | None = None
    """The most one squared second difference counts (``None``: no cap, files written
    before the cap was learned)."""


@dataclass(frozen=True, slots=True)
class RateSpec:
    """The most a climbing signal changes per second between consecutive samples, the
    time between them taken as at least ``period``."""

    at_most: float
    period: float


@dataclass(frozen=True, slots=True)
class LivenessSpec:
    name: str
    signal: SignalRef
    repeats: int | None
    noise: NoiseSpec | None
    wrap: bool = False
    rate: RateSpec | None = None


class _Signal:
    __slots__ = ("blocks", "cap", "cusum", "last", "last_d", "last_t", "last_z", "noise",
                 "rate", "reader", "run", "spec", "sq", "sq_n", "step", "wrap")

    def __init__(self, spec: LivenessSpec) -> None:
        self.spec = spec
        self.wrap, self.rate, self.noise = spec.wrap, spec.rate, spec.noise
        self.cap = math.inf if spec.noise is None or spec.noise.cap is None else spec.noise.cap
        self.reader = SignalReader(spec.signal)
        self.cusum = (Cusum(spec.noise.cusum, two_sided=False) if spec.noise is not None
                      else None)
        self.restart()
        self.step = 0.0
        """The fastest change per second since the last evaluation (``rate``)."""
        self.blocks = 0
        self.last_z = math.nan

    def restart(self) -> None:
        """Forget the samples before a gap: the next one starts a new difference chain."""
        self.last = math.nan
        self.last_t = math.nan
        self.last_d = math.nan
        self.run = 0
        self.sq = 0.0
        self.sq_n = 0

    def add(self, x: float, t: float) -> None:
        last, last_t = self.last, self.last_t
        self.last, self.last_t = x, t
        if last != last:  # NaN: the first sample of a chain
            return
        self.run = self.run + 1 if x == last else 0
        d = wrapped_difference(x, last) if self.wrap else x - last
        rate = self.rate
        if rate is not None:
            self.step = max(self.step, abs(d) / max(t - last_t, rate.period))
        noise = self.noise
        if noise is None or self.cusum is None:
            return
        last_d = self.last_d
        self.last_d = d
        if last_d != last_d:
            return
        d -= last_d
        sq = d * d
        self.sq += sq if sq < self.cap else self.cap
        self.sq_n += 1
        if self.sq_n >= noise.block:
            self.last_z = (math.log(self.sq / self.sq_n + TINY) - noise.mean) / noise.std
            self.cusum.update(self.last_z)
            self.blocks += 1
            self.sq = 0.0
            self.sq_n = 0

    def problem(self) -> str | None:
        spec = self.spec
        if spec.repeats is not None and self.run + 1 >= spec.repeats:
            return (f"{spec.name} stuck: {self.run + 1} equal samples in a row "
                    f"({self.last:.6g})")
        if spec.rate is not None and self.step > spec.rate.at_most:
            return (f"{spec.name} stepped: changed {self.step:.4g} a second between samples "
                    f"(at most {spec.rate.at_most:.4g}: it climbs smoothly)")
        if self.cusum is not None and self.cusum.alarm:
            return (f"{spec.name} noise burst: log squared difference {self.last_z:+.1f} "
                    f"std, CUSUM {self.cusum.statistic:.1f} >= {self.cusum.spec.h:.1f}")
        return None


class LivenessObserver(ObserverBase):
    """Stuck values and noise bursts of the numeric signals of one topic."""

    type_name: ClassVar[str] = "liveness"

    def __init__(self, topic: str, signals: Sequence[LivenessSpec], fresh: float = 1.0,
                 every: float = 1.0) -> None:
        if not signals:
            raise ValueError("a liveness observer needs at least one signal")
        self.topic = topic
        self.resource = Resource(topic=topic)
        self.interval = every
        self.fresh = fresh
        self._signals = [_Signal(s) for s in signals]
        self._last_time = -math.inf
        self._undecodable = 0

    def interest(self) -> Interest:
        return Interest(decoded=frozenset({self.topic}))

    def quantity_names(self) -> tuple[str, ...]:
        return tuple(n for s in self._signals for n in (f"{s.spec.name}_repeats",
                                                        f"{s.spec.name}_noise_cusum"))

    def on_message(self, msg: MessageArrival) -> None:
        if msg.topic != self.topic:
            return
        try:
            value = msg.value
        except Exception:  # the robot's garbage, never the black box's crash
            value = None
        if value is None:
            self._undecodable += 1
            return
        resumed = msg.time - self._last_time > self.fresh
        self._last_time = msg.time
        for s in self._signals:
            if resumed:
                s.restart()
            x = s.reader.read_arrival(msg, value)
            if x is not None:
                s.add(x, msg.time)

    def evaluate(self, now: float) -> list[Observation]:
        values: dict[str, float] = {}
        undecoded = self._undecoded(values)
        if now - self._last_time > self.fresh:
            return [self.unavailable(
                now, f"no message on {self.topic} within {self.fresh:g} s{undecoded}", values)]
        problems: list[str] = []
        waiting: list[str] = []
        for s in self._signals:
            values[f"{s.spec.name}_repeats"] = float(s.run + 1)
            if s.cusum is not None:
                values[f"{s.spec.name}_noise_cusum"] = round(s.cusum.statistic, 4)
                if s.blocks == 0:
                    waiting.append(s.spec.name)
            problem = s.problem()
            s.step = 0.0  # a step fails the one evaluation after it
            if problem:
                problems.append(problem)
        if problems:
            return [Observation(now, self.type_name, self.resource, Code.NO_STATE_FITS,
                                values=values, message="; ".join(problems) + undecoded)]
        if waiting:
            return [self.unavailable(
                now, f"waiting for a first block of {', '.join(waiting)}{undecoded}", values)]
        return [Observation(now, self.type_name, self.resource, Code.GENERAL_OK, values=values,
                            message=f"{len(self._signals)} signals alive{undecoded}")]

    def _undecoded(self, values: dict[str, float]) -> str:
        """The messages since the last evaluation that did not decode, as a clause of the
        observation's message and ``values["undecodable"]`` (they give the signals no
        sample, so the operator reads why a check waits or goes stale); counted afresh."""
        count, self._undecodable = self._undecodable, 0
        if not count:
            return ""
        values["undecodable"] = float(count)
        return f"; {count} messages of {self.topic} did not decode since the last evaluation"

    def describe(self) -> str:
        parts = []
        for s in self._signals:
            spec = s.spec
            checks = []
            if spec.repeats is not None:
                checks.append(f"stuck at {spec.repeats} equal samples")
            if spec.noise is not None:
                checks.append(f"noise CUSUM h {spec.noise.cusum.h:g} over blocks of "
                              f"{spec.noise.block}")
            if spec.rate is not None:
                checks.append(f"changes at most {spec.rate.at_most:g} a second")
            parts.append(f"{spec.signal.field}: {', '.join(checks) or 'nothing'}")
        return f"liveness {self.topic}: {'; '.join(parts)}, every {self.interval:g} s"


def _signal(node: ConfigNode, topic: str, names: set[str]) -> LivenessSpec:
    node.check_keys(("name", "field", "repeats", "noise", "wrap", "rate"))
    name_node = node["name"]
    name = name_node.str()
    if not name or not set(name) <= _NAME_CHARS or name[0].isdigit():
        raise name_node.error(f"signal name {name!r} must be letters, digits and '_', not "
                              "starting with a digit")
    if name in names:
        raise name_node.error(f"signal {name!r} named twice")
    names.add(name)
    ref = read_signal_ref(ConfigNode.mapping({"topic": ConfigNode.scalar(topic, node),
                                             "field": node["field"]}, node))
    repeats_node = node.get("repeats")
    repeats = None if repeats_node is None or repeats_node.is_null else repeats_node.int(min=2)
    noise_node = node.get("noise")
    noise = None
    if noise_node is not None and not noise_node.is_null:
        noise_node.check_keys(("block", "mean", "std", "cusum", "cap"))
        cap_node = noise_node.get("cap")
        noise = NoiseSpec(noise_node["block"].int(min=2), noise_node["mean"].float(),
                          noise_node["std"].float(min=0.0, min_exclusive=True),
                          CusumSpec.read(noise_node["cusum"]),
                          None if cap_node is None or cap_node.is_null
                          else cap_node.float(min=0.0, min_exclusive=True))
    wrap = node.get("wrap")
    rate_node = node.get("rate")
    rate = None
    if rate_node is not None and not rate_node.is_null:
        rate_node.check_keys(("at_most", "period"))
        rate = RateSpec(rate_node["at_most"].float(min=0.0, min_exclusive=True),
                        rate_node["period"].float(min=0.0, min_exclusive=True))
    return LivenessSpec(name, ref, repeats, noise, wrap.bool() if wrap is not None else False,
                        rate)


def liveness_from_config(node: ConfigNode) -> LivenessObserver:
    node.check_keys((*COMMON_KEYS, "topic", "fresh", "signals"))
    topic = read_name(node, "topic")
    items = node["signals"].list()
    if not items:
        raise node["signals"].error("signals lists no signal")
    names: set[str] = set()
    specs = [_signal(item, topic, names) for item in items]
    fresh = node.get("fresh")
    return LivenessObserver(topic, specs,
                            fresh.float(min=0.0, min_exclusive=True) if fresh else 1.0,
                            read_every(node))


OBSERVERS.add("liveness", ObserverKind("liveness", liveness_from_config, Subject.TOPIC, (),
                                       judges=Mode.RIGHT, exonerates=False,
                                       judges_alive=True), example={
    "type": "liveness", "topic": "/battery", "fresh": 1.2,
    "signals": [{"name": "voltage", "field": "voltage", "repeats": 5,
                 "noise": {"block": 5, "mean": -7.34, "std": 0.77, "cap": 0.0162,
                           "cusum": {"k": 0.5, "h": 11.2}}}]})
