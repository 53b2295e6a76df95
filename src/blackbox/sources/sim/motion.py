"""Shared motion of a simulated robot: latent signals several sensors measure at once.

A differential-drive robot's commanded velocity, wheel odometry and IMU yaw rate all follow
the same motion, so they are correlated; a fault in one sensor breaks that. A motion signal
is a mean plus a sum of sines (deterministic in time, so a seed changes only the noise);
a topic's numeric value follows motion signals with a gain each (``follows:`` in
docs/simulator.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from blackbox.config.node import ConfigNode


@dataclass(frozen=True, slots=True)
class Sine:
    amplitude: float
    period: float
    phase: float = 0.0


@dataclass(frozen=True, slots=True)
class MotionSignal:
    """``mean + sum(amplitude * sin(2 pi t / period + phase))``."""

    name: str
    mean: float = 0.0
    terms: tuple[Sine, ...] = ()

    def at(self, t: float) -> float:
        return self.mean + sum(s.amplitude * math.sin(2.0 * math.pi * t / s.period + s.phase)
                               for s in self.terms)


def motion_from_config(node: ConfigNode) -> dict[str, MotionSignal]:
    """``motion: {v: {mean: 0.3, sines: [{amplitude: 0.4, period: 23}]}}``."""
    out: dict[str, MotionSignal] = {}
    for name, item in node.items():
        item.check_keys(["mean", "sines"])
        terms: list[Sine] = []
        sines = item.get("sines")
        for s in sines.list() if sines is not None else []:
            s.check_keys(["amplitude", "period", "phase"])
            terms.append(Sine(s["amplitude"].float(),
                              s["period"].float(min=0.0, min_exclusive=True),
                              s["phase"].float() if s.get("phase") is not None else 0.0))
        mean = item["mean"].float() if item.get("mean") is not None else 0.0
        out[name] = MotionSignal(name, mean, tuple(terms))
    return out
