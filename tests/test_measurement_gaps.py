"""Measurement gaps: an interval the black box could not measure is left unjudged by every
observer, the operator is told "not measured from ... to ...", and a real fault during the
gap still shows once measurement resumes (the real pipeline over a replayed event stream;
the live sources that raise gaps are tests/test_gaps_ros1.py)."""

from __future__ import annotations

from collections.abc import Sequence

from blackbox.evaluate.metrics import episodes
from blackbox.events import Event, GraphSnapshot, MeasurementGap, MessageArrival, NodeInfo
from blackbox.model import BlackBoxEvent, Code, Observation
from blackbox.observe.build import build_observers, load_config_text
from blackbox.pipeline import Pipeline
from blackbox.sinks import SinkBase
from blackbox.sources.clockwatch import ClockWatch
from blackbox.sources.memory import MemorySource

TOPIC = "/camera"
CONFIG = """
version: 1
observers:
  - type: hz
    topic: /camera
    filter: {type: mean, window_size: 10, deviation: std_deviation}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.1, std_deviation: 0.01}}}
  - {type: timeout, topic: /camera, timeout: 1.0}
  - {type: activated, node: /cam}
"""


class Seen(SinkBase):
    def __init__(self) -> None:
        self.observations: list[Observation] = []
        self.events: list[BlackBoxEvent] = []

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self.observations.extend(observations)

    def on_event(self, event: BlackBoxEvent) -> None:
        self.events.append(event)

    def faulty(self) -> list[Observation]:
        """The red lights: faulty verdicts (``NOT_AVAILABLE`` is no verdict)."""
        return [o for o in self.observations if o.faulty and o.code != Code.NOT_AVAILABLE]

    def gap_events(self) -> list[BlackBoxEvent]:
        return [e for e in self.events if e.kind in ("not_measured", "measured_again")]


def arrivals(start: float, end: float, period: float = 0.1) -> list[Event]:
    n = round((end - start) / period)
    return [MessageArrival(start + k * period, TOPIC, "/cam", 100) for k in range(n)]


def graphs(start: float, end: float, alive: bool = True) -> list[Event]:
    return [GraphSnapshot(start + k * 0.5, {"/cam": NodeInfo("/cam", alive)})
            for k in range(int((end - start) / 0.5))]


class PausedSource(MemorySource):
    """Replays events like a live source whose process was stopped from ``start`` to
    ``end``: the poll that should have woken inside the pause wakes at its end and says so
    with a gap of everything, as the live sources' clock watch does."""

    def __init__(self, events: list[Event], start: float, end: float) -> None:
        super().__init__(events)
        self.pause: tuple[float, float] | None = (start, end)

    def poll(self, until: float) -> list[Event]:
        if self.pause is None or until <= self.pause[0]:
            return super().poll(until)
        start, end = self.pause
        self.pause = None
        self._now = end
        return [MeasurementGap(end, start, end, "paused"), *super().poll(until)]


def run(events: list[Event], duration: float, source: MemorySource | None = None) -> Seen:
    seen = Seen()
    observers = build_observers(load_config_text(CONFIG, "gaps.yaml"))
    Pipeline(source or MemorySource(events), observers, [seen]).run(duration)
    return seen


def switch(gap_from: float, gap_to: float) -> list[Event]:
    """A counters/subscription switch as the ROS 1 source shows it: a 10 Hz topic, nothing
    for two seconds, then a burst of the messages the new path had buffered."""
    burst = [MessageArrival(gap_to + k * 0.001, TOPIC, "/cam", 100) for k in range(20)]
    return [*arrivals(0.0, gap_from), *burst, *arrivals(gap_to + 0.1, 20.0),
            *graphs(0.0, 20.0)]


def test_without_a_gap_event_a_switch_reads_as_a_time_out_and_a_wrong_rate() -> None:
    seen = run(switch(5.0, 7.0), 20.0)
    assert {o.observer for o in seen.faulty()} == {"hz", "timeout"}


def test_a_gap_leaves_rate_and_time_out_unjudged_and_the_operator_is_told() -> None:
    events = [*switch(5.0, 7.0), MeasurementGap(5.0, 5.0, None, "switching", topic=TOPIC),
              MeasurementGap(7.0, 5.0, 7.0, "switching", topic=TOPIC)]
    seen = run(events, 20.0)
    assert seen.faulty() == []
    during = [o for o in seen.observations if 5.0 < o.time < 7.0 and o.observer != "activated"]
    assert during and all(o.code == Code.NOT_AVAILABLE and "not measured since" in o.message
                          for o in during)
    opened, closed = seen.gap_events()
    assert opened.kind == "not_measured" and opened.component == TOPIC
    assert closed.message == f"{TOPIC}: not measured from 5.000 s to 7.000 s (switching)"
    # after the gap both observers judge again, and the topic is healthy
    late = [o for o in seen.observations if o.time > 9.0 and o.observer in ("hz", "timeout")]
    assert late and all(o.code == Code.GENERAL_OK for o in late)


def test_unjudged_observations_are_no_alarm_episode_in_a_campaign() -> None:
    events = [*switch(5.0, 7.0), MeasurementGap(5.0, 5.0, None, "switching", topic=TOPIC),
              MeasurementGap(7.0, 5.0, 7.0, "switching", topic=TOPIC)]
    seen = run(events, 20.0)
    assert any(o.code == Code.NOT_AVAILABLE and o.time > 5.0 for o in seen.observations)
    assert [e for e in episodes(seen.observations) if e.end > 1.0] == []


def test_a_topic_that_stopped_during_the_gap_times_out_once_measuring_resumed() -> None:
    events = [*arrivals(0.0, 5.0), *graphs(0.0, 20.0),
              MeasurementGap(5.0, 5.0, None, "switching", topic=TOPIC),
              MeasurementGap(7.0, 5.0, 7.0, "switching", topic=TOPIC)]
    seen = run(events, 20.0)
    timeouts = [o for o in seen.faulty() if o.observer == "timeout"]
    hz = [o for o in seen.faulty() if o.observer == "hz"]
    assert timeouts and 8.0 < timeouts[0].time <= 8.3  # timeout 1 s after the gap's end
    assert "since measuring resumed" in timeouts[0].message
    assert hz and hz[0].time > 7.0  # the provisional period counts from the gap's end


def test_a_pause_of_the_black_box_restarts_evaluation_at_its_end() -> None:
    """A gap of everything known only afterwards (the black box was paused from 5 to 8 s):
    no evaluation inside it, a probe that failed while paused is not a dead node."""
    events = [*arrivals(0.0, 5.0), *arrivals(8.0, 20.0), *graphs(0.0, 5.0),
              GraphSnapshot(7.9, {"/cam": NodeInfo("/cam", False)}), *graphs(8.5, 20.0)]
    seen = run(events, 20.0, PausedSource(events, 5.0, 8.0))
    assert seen.faulty() == []
    assert not [o for o in seen.observations if 5.0 < o.time < 8.0]
    [closed] = seen.gap_events()
    assert closed.component == "blackbox" and "everything: not measured from 5.000 s" \
        in closed.message


def test_a_graph_gap_is_reported_but_leaves_every_verdict_alone() -> None:
    events = [*arrivals(0.0, 10.0), *graphs(0.0, 10.0),
              MeasurementGap(3.0, 3.0, None, "master gone", graph=True),
              MeasurementGap(6.0, 3.0, 6.0, "master gone", graph=True)]
    seen = run(events, 10.0)
    assert not [o for o in seen.observations if o.code == Code.NOT_AVAILABLE and o.time > 3]
    assert [e.message for e in seen.gap_events()][-1].startswith(
        "the robot's graph: not measured from 3.000 s to 6.000 s")


class Clocks:
    """A wall clock the test steps and a monotonic clock it advances."""

    def __init__(self) -> None:
        self.wall_now = 1000.0
        self.mono_now = 50.0

    def wall(self) -> float:
        return self.wall_now

    def mono(self) -> float:
        return self.mono_now

    def advance(self, seconds: float) -> None:
        self.wall_now += seconds
        self.mono_now += seconds


def test_clock_watch_tells_a_step_either_way_and_a_late_wake_from_normal_polls() -> None:
    c = Clocks()
    watch = ClockWatch(c.wall, c.mono)
    assert watch.check() is None
    c.advance(0.5)
    assert watch.check(expected=1000.5) is None
    c.wall_now += 30.0  # NTP steps forward
    forward = watch.check()
    assert forward is not None and forward.everything
    assert (forward.start, forward.end) == (1000.5, 1030.5) and "forward by 30" in forward.reason
    c.wall_now -= 40.0
    back = watch.check()
    assert back is not None and back.end == 990.5 and "back by 40" in back.reason
    c.advance(0.2)
    assert watch.check() is None
    c.advance(3.0)  # asked to wake at 990.9, woke at 993.7: not run for 2.8 s
    paused = watch.check(expected=990.9)
    assert paused is not None and (paused.start, paused.end) == (990.7, 993.7)
    assert "did not run for 2.8 s" in paused.reason
