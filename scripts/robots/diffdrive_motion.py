"""The motion every node of the real diffdrive robots measures (issue 22), pure Python.

Each node is its own process; they agree on the robot's motion because each computes it
from the same ``epoch`` (wall-clock start) and ``seed``: forward speed ``v`` and yaw rate
``w`` are sums of sines scaled by an operating mode (stand, straight, turn) drawn from the
seed, the battery current grows with ``|v|`` and ``|w|`` and its voltage sags with it.
No ROS import here, so the ROS 1 nodes (``/usr/bin/python3``) and the ROS 2 nodes (the
project's venv) share one model.
"""

from __future__ import annotations

import bisect
import math
import random

MODES = (("straight", 15.0, 40.0), ("stand", 6.0, 15.0), ("turn", 6.0, 15.0))
SCALES = {"straight": (1.0, 0.1), "stand": (0.0, 0.0), "turn": (0.2, 1.0)}
RAMP = 1.5


class DiffdriveMotion:
    """``v(t)``, ``w(t)``, ``current(t)``, ``voltage(t)`` for ``t`` seconds after the epoch."""

    def __init__(self, seed: int) -> None:
        rng = random.Random(f"blackbox-real-diffdrive:{seed}")
        self.starts = [0.0]
        self.modes = [MODES[0][0]]
        end = rng.uniform(MODES[0][1], MODES[0][2])
        while end < 24 * 3600.0:
            name, lo, hi = rng.choice([m for m in MODES if m[0] != self.modes[-1]])
            self.starts.append(end)
            self.modes.append(name)
            end += rng.uniform(lo, hi)

    def mode(self, t: float) -> str:
        return self.modes[bisect.bisect_right(self.starts, max(t, 0.0)) - 1]

    def _scales(self, t: float) -> tuple[float, float]:
        k = bisect.bisect_right(self.starts, max(t, 0.0)) - 1
        sv, sw = SCALES[self.modes[k]]
        since = t - self.starts[k]
        if k == 0 or since >= RAMP:
            return sv, sw
        pv, pw = SCALES[self.modes[k - 1]]
        a = since / RAMP
        return pv + (sv - pv) * a, pw + (sw - pw) * a

    def v(self, t: float) -> float:
        wave = (0.3 + 0.4 * math.sin(2 * math.pi * t / 23.0)
                + 0.15 * math.sin(2 * math.pi * t / 7.1 + 0.5))
        return self._scales(t)[0] * wave

    def w(self, t: float) -> float:
        wave = (0.5 * math.sin(2 * math.pi * t / 17.0 + 1.0)
                + 0.2 * math.sin(2 * math.pi * t / 5.3))
        return self._scales(t)[1] * wave

    def current(self, t: float) -> float:
        return 1.5 + 4.0 * abs(self.v(t)) + 2.0 * abs(self.w(t))

    def voltage(self, t: float) -> float:
        """25.2 V less the sag of the current (0.08 ohm) and a slow discharge (~1 V/h)."""
        return 25.2 - 0.08 * self.current(t) - 0.00028 * t
