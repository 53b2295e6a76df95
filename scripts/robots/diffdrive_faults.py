"""The fault schedule of the real diffdrive robots, drawn from a seed (issue 22), pure Python.

Every node of ``scripts/ros1_robot/diffdrive_robot.py`` and ``scripts/ros2_robot/
diffdrive_robot.py`` draws the same schedule from ``(seed, start, duration)`` and applies the
value faults on its own fields itself, at the motion's clock (seconds after the robot's
epoch); the harness (``benchmarks/learned_campaign_real.py``) draws it too, so it knows the
ground truth without talking to the nodes, and performs the two process faults, which a
node cannot do to itself: ``kill`` (SIGKILL, started again at the end) and ``stall``
(SIGSTOP of the publisher, SIGCONT at the end).

The draws are the simulated campaign's (``random_campaign`` in
``src/blackbox/sources/sim/faults.py`` with ``moving_only``, as ``benchmarks/
learned_campaign.py`` calls it), made by the same functions
(``src/blackbox/sources/sim/fault_draws.py``, standard library only, loaded here by its
path because the package is not installed for ``/usr/bin/python3``): fault starts a
Poisson process with a 10 s mean gap after a 5 s warm-up, lengths 5-15 s, the kind uniform
among the seven, the component uniform among the free ones (one fault per node at a time,
5 s apart), the field uniform among the topic's moving fields; offsets 4-10 and drift rates
0.5-2 per second times the field's own noise, scale factors 0.5-0.8 or 1.2-1.6, noise of
0.2-0.5 of the field's healthy spread and at least 3-6 times its own noise, stuck at the
last value before the fault. A fault is therefore inside the signal's normal range. No ROS
import: the ROS 1 nodes run under Debian's ``/usr/bin/python3``, the ROS 2 nodes and the
harness under the project's venv.
"""

from __future__ import annotations

import importlib.util
import random
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

from diffdrive_motion import DiffdriveMotion


def _load_draws() -> ModuleType:
    """``blackbox/sources/sim/fault_draws.py`` of this checkout, by its path (once per
    process, under a name of its own so it never shadows or imports the package)."""
    name = "blackbox_sim_fault_draws"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[2] / "src" / "blackbox" / "sources" / "sim" \
            / "fault_draws.py"
        spec = importlib.util.spec_from_file_location(name, path)
        assert spec is not None and spec.loader is not None, path
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


fault_draws = _load_draws()

KINDS = ("stuck", "drift", "offset", "scale", "noise", "kill", "stall")
VALUE_KINDS = frozenset({"stuck", "drift", "offset", "scale", "noise"})

TOPICS = {"/cmd_vel": "/teleop", "/joint_states": "/base_driver", "/odom/twist": "/odometry",
          "/imu/data": "/imu_driver", "/battery_state": "/battery_monitor"}
"""Topic -> publishing node (both robots)."""

Clean = Callable[[DiffdriveMotion, float], float]

FIELDS: dict[tuple[str, str], tuple[float, Clean]] = {
    ("/cmd_vel", "linear.x"): (0.01, lambda m, t: m.v(t)),
    ("/cmd_vel", "angular.z"): (0.01, lambda m, t: m.w(t)),
    ("/joint_states", "velocity[0]"): (0.1, lambda m, t: (m.v(t) - 0.2 * m.w(t)) / 0.1),
    ("/joint_states", "velocity[1]"): (0.1, lambda m, t: (m.v(t) + 0.2 * m.w(t)) / 0.1),
    ("/odom/twist", "twist.linear.x"): (0.015, lambda m, t: m.v(t)),
    ("/odom/twist", "twist.angular.z"): (0.02, lambda m, t: m.w(t)),
    ("/imu/data", "angular_velocity.z"): (0.02, lambda m, t: m.w(t)),
    ("/battery_state", "voltage"): (0.02, lambda m, t: m.voltage(t)),
    ("/battery_state", "current"): (0.05, lambda m, t: m.current(t)),
}
"""(topic, field) of every value that follows the motion -> (its noise std, its clean value
at motion time t). ``/imu/data`` ``linear_acceleration.z`` is a constant (gravity) and, as in
the simulated campaign's ``moving_only``, not faulted."""

SEPARATION = 5.0


@dataclass(frozen=True, slots=True)
class ScheduledFault:
    """One fault; ``start`` and ``end`` are motion times (seconds after the robot's epoch).
    ``component`` is the node (kill) or topic (the others); ``field`` names the value a value
    fault acts on."""

    kind: str
    component: str
    start: float
    end: float
    params: dict[str, float] = field(default_factory=dict)
    field: str | None = None

    @property
    def node(self) -> str:
        return self.component if self.kind == "kill" else TOPICS[self.component]


_SPREADS: dict[tuple[str, str], float] = {}


def healthy_spread(topic: str, name: str, horizon: float = 600.0, step: float = 0.5) -> float:
    """Standard deviation of the healthy value over ``horizon`` seconds of the seed-0
    motion, its own noise included (the simulated campaign's definition)."""
    key = (topic, name)
    if key not in _SPREADS:
        sigma, clean = FIELDS[key]
        motion = DiffdriveMotion(0)
        values = [clean(motion, k * step) for k in range(int(horizon / step))]
        _SPREADS[key] = fault_draws.spread(values, sigma)
    return _SPREADS[key]


def _params(rng: random.Random, kind: str, topic: str, name: str) -> dict[str, float]:
    sigma = FIELDS[(topic, name)][0]
    if kind == "offset":
        return fault_draws.offset(rng, sigma)
    if kind == "drift":
        return fault_draws.drift(rng, sigma)
    if kind == "scale":
        return fault_draws.scale(rng)
    if kind == "noise":
        return fault_draws.noise(rng, healthy_spread(topic, name), sigma)
    return {}


def schedule(seed: int, start: float, duration: float,
             kinds: Sequence[str] = KINDS) -> list[ScheduledFault]:
    """The faults of ``seed`` over motion times ``[start + 5 s, start + duration)``."""
    rng = random.Random(f"blackbox-real-diffdrive-faults:{seed}")
    nodes = sorted(set(TOPICS.values()))
    free_at = {n: 0.0 for n in nodes}

    def free(kind: str, t: float) -> list[str]:
        if kind == "kill":
            return [n for n in nodes if free_at[n] <= t]
        return [c for c in sorted(TOPICS) if free_at[TOPICS[c]] <= t]

    faults: list[ScheduledFault] = []
    for draw in fault_draws.draws(rng, duration, kinds, free):
        name = None
        params: dict[str, float] = {}
        if draw.kind in VALUE_KINDS:
            name = rng.choice([f for (tp, f) in FIELDS if tp == draw.component])
            params = _params(rng, draw.kind, draw.component, name)
        fault = ScheduledFault(draw.kind, draw.component, round(start + draw.t, 3),
                               round(start + draw.t + draw.length, 3), params, name)
        faults.append(fault)
        free_at[fault.node] = draw.t + draw.length + SEPARATION
    return faults


class FaultPlan:
    """What one node applies to the values it publishes: the value faults of the schedule
    on its own topic. An empty plan (``duration`` 0) changes nothing."""

    def __init__(self, topic: str, seed: int, start: float, duration: float) -> None:
        self.faults = [f for f in schedule(seed, start, duration) if f.component == topic
                       and f.kind in VALUE_KINDS] if duration > 0 else []
        self.last: dict[str, float] = {}
        self.noise = random.Random(f"blackbox-real-diffdrive-fault-noise:{seed}:{topic}")

    def apply(self, name: str, t: float, value: float) -> float:
        """``value`` of field ``name`` at motion time ``t``, as the fault active then makes it."""
        fault = next((f for f in self.faults if f.field == name and f.start <= t < f.end),
                     None)
        if fault is None:
            self.last[name] = value
            return value
        if fault.kind == "stuck":
            return self.last.setdefault(name, value)
        if fault.kind == "offset":
            return value + fault.params["value"]
        if fault.kind == "drift":
            return value + fault.params["rate"] * (t - fault.start)
        if fault.kind == "scale":
            return value * fault.params["factor"]
        return value + self.noise.gauss(0.0, fault.params["sigma"])
