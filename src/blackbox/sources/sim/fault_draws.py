"""The random draws of a fault campaign, shared by the simulator and the real robots.

``random_campaign`` (:mod:`.faults`) and the real diffdrive robots' schedule
(``scripts/robots/diffdrive_faults.py``) draw the same way: fault starts a Poisson process
after a warm-up, the kind uniform among those with a free component, the component uniform
among the free ones, the length uniform, and parameters large enough to be a real fault but
inside the signal's normal range. Both draw through these functions, in the same order, so
a fault kind means the same in both worlds and a seed's schedule cannot drift apart in two
copies.

Standard library only and no blackbox import: the robots' ROS 1 nodes load this file by its
path under Debian's ``/usr/bin/python3``, where the package is not installed. Every value is
rounded where its caller always rounded it; changing an expression or the order of draws
changes every recorded campaign (``tests/test_fault_draws.py`` holds them).
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

WARMUP = 5.0
"""Seconds before the first fault may start."""
MEAN_GAP = 10.0
"""Mean seconds between fault starts."""
LENGTHS = (5.0, 15.0)
"""Shortest and longest fault, seconds."""

FreeComponents = Callable[[str, float], Sequence[str]]
"""``(kind, t)`` -> the components a fault of ``kind`` may start on at ``t`` (none busy)."""


@dataclass(frozen=True, slots=True)
class Draw:
    """A fault of ``kind`` on ``component`` from campaign time ``t`` for ``length`` seconds,
    both unrounded (each caller rounds its times as it always did)."""

    t: float
    kind: str
    component: str
    length: float


def draws(rng: random.Random, duration: float, kinds: Iterable[str], free: FreeComponents,
          *, warmup: float = WARMUP, mean_gap: float = MEAN_GAP,
          lengths: tuple[float, float] = LENGTHS) -> Iterator[Draw]:
    """The faults starting in ``[warmup, duration)``, lazily: the caller draws a fault's
    field and parameters from ``rng`` and marks its component busy before asking for the
    next one, which ``free`` then leaves out. A start with no free component is skipped."""
    kinds = tuple(kinds)
    t = warmup
    while True:
        t += rng.expovariate(1.0 / mean_gap)
        if t >= duration:
            return
        choices: dict[str, Sequence[str]] = {}
        for kind in kinds:
            pool = free(kind, t)
            if pool:
                choices[kind] = pool
        if not choices:
            continue
        kind = rng.choice(sorted(choices))
        component = rng.choice(choices[kind])
        yield Draw(t, kind, component, rng.uniform(*lengths))


def sign(rng: random.Random) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def either(rng: random.Random, low: tuple[float, float], high: tuple[float, float]) -> float:
    """Uniform in ``low`` or in ``high``, each half the time: a factor that is never near 1."""
    return rng.uniform(*(low if rng.random() < 0.5 else high))


def offset(rng: random.Random, unit: float) -> dict[str, float]:
    """4-10 ``unit`` (the signal's noise) up or down."""
    return {"value": round(sign(rng) * rng.uniform(4.0, 10.0) * unit, 4)}


def drift(rng: random.Random, unit: float) -> dict[str, float]:
    """0.5-2 ``unit`` (the signal's noise) a second, up or down."""
    return {"rate": round(sign(rng) * rng.uniform(0.5, 2.0) * unit, 4)}


def scale(rng: random.Random) -> dict[str, float]:
    return {"factor": round(either(rng, (0.5, 0.8), (1.2, 1.6)), 3)}


def noise(rng: random.Random, spread: float, own: float) -> dict[str, float]:
    """Inside the normal range: 0.2-0.5 of the signal's healthy ``spread``, but at least
    3-6 times its ``own`` measurement noise, so it is a fault and not more of the same."""
    return {"sigma": round(max(rng.uniform(0.2, 0.5) * spread, rng.uniform(3.0, 6.0) * own,
                               1e-3), 4)}


def rate(rng: random.Random) -> dict[str, float]:
    return {"factor": round(either(rng, (0.3, 0.6), (1.6, 2.5)), 3)}


def cpu_hog(rng: random.Random) -> dict[str, float]:
    return {"percent": round(rng.uniform(85.0, 100.0), 1)}


def memory_growth(rng: random.Random) -> dict[str, float]:
    return {"rate": float(round(rng.uniform(2e6, 20e6)))}


def spread(values: Sequence[float], own: float) -> float:
    """Standard deviation of a healthy signal sampled as ``values`` (what it does with the
    robot's motion), its ``own`` measurement noise added: the scale of a noise fault."""
    mean = sum(values) / len(values)
    var = sum((x - mean) ** 2 for x in values) / len(values)
    return math.sqrt(var + own ** 2)
