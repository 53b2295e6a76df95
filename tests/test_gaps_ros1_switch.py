"""The switch of a counted topic to the black box's own subscription, replayed through the
ROS 1 source's bookkeeping without a robot: the counted arrivals already queued and the
first subscribed messages must never interleave (no doubled rate), and the thesis's ``hz``
observer must never judge the switch (docs/ros1.md, "measurement gaps")."""

from __future__ import annotations

import time
from itertools import pairwise
from pathlib import Path

from blackbox.events import Event, MeasurementGap, MessageArrival
from blackbox.model import Code, Observation
from blackbox.observe.build import build_observers, load_config
from blackbox.observe.observers.hz import HzObserver
from blackbox.sources.ros1.source import Ros1Settings, Ros1Source

THESIS = Path(__file__).resolve().parent.parent / "src" / "blackbox" / "configs" / "thesis.yaml"
AUDIO, PUBLISHER = "/audio", "/audio_capture"
PERIOD = 0.03  # /audio at 33.3 Hz
ROUND = 0.45  # the graph period


def thesis_hz(topic: str) -> HzObserver:
    [hz] = [o for o in build_observers(load_config(THESIS))
            if isinstance(o, HzObserver) and o.group.topic == topic]
    return hz


def one_round(start: float) -> list[MessageArrival]:
    """A round's counts as the counters give them: ROUND s of /audio, stamped from
    ``start`` (the source moves them to continue the previous round's)."""
    n = round(ROUND / PERIOD)
    return [MessageArrival(start + ROUND * (k + 1) / n, AUDIO, PUBLISHER, 480)
            for k in range(n)]


def judge(hz: HzObserver, events: list[Event], horizon: float) -> Observation:
    for e in events:
        if isinstance(e, MeasurementGap) and e.topic in (None, AUDIO):
            hz.on_gap(e)
        elif isinstance(e, MessageArrival) and e.topic == AUDIO:
            hz.on_message(e)
    [verdict] = hz.evaluate(horizon)
    return verdict


def test_counted_arrivals_queued_ahead_and_the_subscription_never_interleave() -> None:
    """Three rounds of counts in quick succession (a slow round's replies, then quick ones)
    queue /audio's counted arrivals well over a second ahead of now; then its only on-robot
    subscriber dies and the black box subscribes, its first message 50 ms later. Before,
    the gap ended at that first message, the rest of the counted arrivals came between the
    subscribed ones (twice the rate for over a second: a too-short period, an hz false
    alarm 1-2 s after each kill of /Signal_generator in the real campaign). The gap must
    last until the counted arrivals end; from then on one stream at the true rate."""
    source = Ros1Source("http://127.0.0.1:9/", Ros1Settings())  # never started: no robot
    key = (AUDIO, PUBLISHER)
    start = time.time()
    for _ in range(3):
        source._push_counted(time.time(), one_round(time.time()))
    ahead = source._counted_until[key]
    assert ahead > start + 1.2, "the counts were not queued ahead"
    source._switch_to_subscription(key, time.time())
    first = time.time() + 0.05
    subscribed = [MessageArrival(first + PERIOD * k, AUDIO, PUBLISHER, 480)
                  for k in range(110)]
    source._push_batch(subscribed[:1])  # the new connection's first read, alone
    source._push_batch(subscribed[1:])  # the kernel's stamps; handed out at their horizons
    hz = thesis_hz(AUDIO)
    handed: list[Event] = []
    verdicts: list[Observation] = []
    for k in range(1, 8):  # the pipeline's evaluations, every 0.5 s
        horizon = start + 0.5 * k
        events = source.poll(horizon)
        handed.extend(events)
        verdicts.append(judge(hz, events, horizon))
    faulty = [(round(v.time - start, 2), v.message) for v in verdicts
              if v.code not in (Code.GENERAL_OK, Code.NOT_AVAILABLE)]
    assert faulty == []  # before: 66 Hz at the three evaluations after the switch
    ends = [g.end for g in handed if isinstance(g, MeasurementGap) and g.end is not None]
    assert ends and max(ends) >= ahead, f"the gap ended at {ends}, counts ran to {ahead}"
    after = sorted(a.time for a in handed if isinstance(a, MessageArrival)
                   and a.time > max(ends))
    assert after and min(b - a for a, b in pairwise(after)) > 0.02, \
        "counted and subscribed arrivals interleave after the gap"
    assert any(v.code == Code.GENERAL_OK for v in verdicts[-2:]), \
        f"never judged again after the switch: {[v.message for v in verdicts]}"
