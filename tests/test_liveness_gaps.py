"""A learned liveness check across a silence (issue 22, real middleware), as specifications.

A node killed and started again, or a publisher stalled and resumed, leaves its topic silent
for seconds while the robot keeps moving. The first sample after the silence differs from
the last one before it by all that motion: not noise. On the real diffdrive robots that
difference raised a noise burst one to three seconds after every restarted node (three false
alarms in a 900 s ROS 1 campaign, ``benchmarks/learned_campaign_real.py``). A topic that
resumes after more than ``fresh`` seconds starts its differences afresh; a noise burst after
the silence is still a noise burst.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from blackbox.config.node import ConfigNode
from blackbox.events import MessageArrival
from blackbox.model import Code, Observation
from blackbox.observe.observers.liveness import LivenessObserver, liveness_from_config

RATE = 20.0
NOISE = 0.01
BLOCK = 10


@dataclass(frozen=True, slots=True)
class Speed:
    x: float


def motion(t: float) -> float:
    return 0.5 * math.sin(2 * math.pi * t / 7.0) + 0.2 * math.sin(2 * math.pi * t / 2.3)


def healthy_noise_statistics(seed: int = 7, blocks: int = 400) -> tuple[float, float]:
    """Mean and std of a block's log mean squared second difference of the healthy signal
    (what ``blackbox learn`` measures)."""
    rng = np.random.default_rng(seed)
    t = np.arange(blocks * BLOCK + 2) / RATE
    x = np.array([motion(v) for v in t]) + rng.normal(0, NOISE, t.size)
    d2 = np.diff(x, 2)[: blocks * BLOCK].reshape(blocks, BLOCK)
    logs = np.log((d2 ** 2).mean(axis=1))
    return float(logs.mean()), float(logs.std())


def observer() -> LivenessObserver:
    mean, std = healthy_noise_statistics()
    return liveness_from_config(ConfigNode.parse(
        "type: liveness\ntopic: /speed\nfresh: 0.5\nsignals:\n"
        f"  - {{name: x, field: x, repeats: 10, noise: {{block: {BLOCK}, mean: {mean:.4f}, "
        f"std: {std:.4f}, cusum: {{k: 0.5, h: 6.0}}}}}}\n"))


def play(obs: LivenessObserver, start: float, end: float, sigma: Callable[[float], float],
         seed: int) -> list[Observation]:
    """Messages at 20 Hz from ``start`` to ``end`` (noise ``sigma(t)``), evaluated twice a
    second; the verdicts."""
    rng = np.random.default_rng(seed)
    out: list[Observation] = []
    k = 0
    while (t := start + k / RATE) < end:
        value = motion(t) + rng.normal(0, sigma(t))
        obs.on_message(MessageArrival(t, "/speed", "/driver", 8, value=Speed(float(value))))
        if k % 10 == 9:
            out.extend(obs.evaluate(t))
        k += 1
    return out


def faulty(verdicts: list[Observation]) -> list[Observation]:
    return [o for o in verdicts if o.code == Code.NO_STATE_FITS]


def test_a_topic_that_resumes_after_a_silence_raises_no_noise_burst() -> None:
    obs = observer()
    before = play(obs, 0.0, 30.0, lambda t: NOISE, seed=1)
    assert faulty(before) == [], "healthy before the silence"
    # 8 s silent (a killed node) while the motion went on, then healthy again.
    after = play(obs, 38.0, 60.0, lambda t: NOISE, seed=2)
    assert faulty(after) == [], [o.message for o in faulty(after)]
    assert any(o.code == Code.GENERAL_OK for o in after), "judged again after the silence"


def test_a_noise_burst_after_a_silence_is_still_found() -> None:
    obs = observer()
    play(obs, 0.0, 30.0, lambda t: NOISE, seed=1)
    after = play(obs, 38.0, 48.0, lambda t: NOISE if t < 41.0 else 10 * NOISE, seed=2)
    burst = faulty(after)
    assert burst, "a tenfold noise from 41 s on is found"
    assert burst[0].time < 43.0 and "noise burst" in burst[0].message, burst[0]


def test_messages_that_do_not_decode_are_counted_in_the_next_observation() -> None:
    """They give the signals no sample, so the operator reads why a check goes stale."""
    obs = observer()
    play(obs, 0.0, 10.0, lambda t: NOISE, seed=3)
    for k in range(4):
        obs.on_message(MessageArrival(10.0 + k / RATE, "/speed", "/driver", 8))
    (stale,) = obs.evaluate(11.0)
    assert stale.code == Code.NOT_AVAILABLE
    assert stale.values["undecodable"] == 4.0
    assert "4 messages of /speed did not decode since the last evaluation" in stale.message
    verdicts = play(obs, 11.0, 13.0, lambda t: NOISE, seed=4)
    assert verdicts and all("undecodable" not in o.values for o in verdicts)
