"""The pipeline feeds events to interested observers, evaluates them on schedule, fans
results out to sinks, and survives broken observers and sinks."""

from __future__ import annotations

from collections.abc import Sequence

from blackbox.events import GraphSnapshot, Interest, MessageArrival, NodeInfo
from blackbox.model import BlackBoxEvent, Code, Diagnosis, Observation, Resource
from blackbox.observe.base import ObserverBase
from blackbox.pipeline import Pipeline
from blackbox.sinks import SinkBase
from blackbox.sources.memory import MemorySource


class CountingObserver(ObserverBase):
    """Counts arrivals on one topic and reports the count at each evaluation."""

    type_name = "counting"

    def __init__(self, topic: str, interval: float = 1.0, fail_on_eval: bool = False) -> None:
        self.topic = topic
        self.interval = interval
        self.count = 0
        self.graphs = 0
        self.fail_on_eval = fail_on_eval

    def interest(self) -> Interest:
        return Interest(topics=frozenset({self.topic}))

    def on_message(self, msg: MessageArrival) -> None:
        if msg.value == "boom":
            raise ValueError("cannot digest boom")
        self.count += 1

    def on_graph(self, graph: GraphSnapshot) -> None:
        self.graphs += 1

    def evaluate(self, now: float) -> list[Observation]:
        if self.fail_on_eval:
            raise RuntimeError("evaluation bug")
        code = Code.GENERAL_OK if self.count else Code.NOT_AVAILABLE
        return [Observation(now, self.type_name, Resource(topic=self.topic), code,
                            values={"count": float(self.count)})]

    def describe(self) -> str:
        return f"counting {self.topic}"


class CollectingSink(SinkBase):
    def __init__(self) -> None:
        self.observations: list[Observation] = []
        self.events: list[BlackBoxEvent] = []
        self.diagnoses: list[Diagnosis] = []
        self.closed = False

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self.observations.extend(observations)

    def on_event(self, event: BlackBoxEvent) -> None:
        self.events.append(event)

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        self.diagnoses.append(diagnosis)

    def close(self) -> None:
        self.closed = True


class BrokenSink(SinkBase):
    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        raise OSError("disk on fire")


def arrivals(topic: str, times: Sequence[float], value: object = 1.0) -> list[MessageArrival]:
    return [MessageArrival(t, topic, "/pub", 10, value=value) for t in times]


def test_messages_reach_only_interested_observers_and_evaluation_follows_interval() -> None:
    a, b = CountingObserver("/a"), CountingObserver("/b", interval=0.5)
    events = arrivals("/a", [0.1, 0.2, 1.5]) + arrivals("/b", [0.3])
    sink = CollectingSink()
    stats = Pipeline(MemorySource(events), [a, b], [sink]).run(duration=2.0)

    assert (a.count, b.count) == (3, 1)
    times_a = [o.time for o in sink.observations if o.resource.topic == "/a"]
    times_b = [o.time for o in sink.observations if o.resource.topic == "/b"]
    assert times_a == [1.0, 2.0]
    assert times_b == [0.5, 1.0, 1.5, 2.0]
    counts_a = [o.values["count"] for o in sink.observations if o.resource.topic == "/a"]
    assert counts_a == [2.0, 3.0]
    assert stats.messages == 4
    assert sink.closed
    assert [e.kind for e in sink.events] == ["start", "stop"]


def test_graph_snapshots_reach_every_observer() -> None:
    obs = CountingObserver("/a")
    graph = GraphSnapshot(0.5, nodes={"/n": NodeInfo("/n", alive=True)})
    Pipeline(MemorySource([graph]), [obs]).run(duration=1.0)
    assert obs.graphs == 1


def test_a_message_an_observer_cannot_digest_is_reported_once_and_the_rest_still_flows() -> None:
    obs = CountingObserver("/a")
    events = arrivals("/a", [0.1]) + arrivals("/a", [0.2, 0.3], value="boom") + \
        arrivals("/a", [0.4])
    sink = CollectingSink()
    stats = Pipeline(MemorySource(events), [obs], [sink]).run(duration=1.0)
    assert obs.count == 2
    assert stats.errors == 2
    errors = [e for e in sink.events if e.kind == "event_error"]
    assert len(errors) == 1 and "cannot digest boom" in errors[0].message


def test_a_failing_observer_becomes_a_general_error_observation() -> None:
    good, bad = CountingObserver("/a"), CountingObserver("/b", fail_on_eval=True)
    sink = CollectingSink()
    Pipeline(MemorySource(arrivals("/a", [0.1])), [good, bad], [sink]).run(duration=1.0)
    codes = sorted(int(o.code) for o in sink.observations)
    assert codes == [Code.GENERAL_ERROR, Code.GENERAL_OK]
    assert any(e.kind == "observer_error" and "evaluation bug" in e.message for e in sink.events)


def test_a_broken_sink_does_not_starve_the_others() -> None:
    sink = CollectingSink()
    Pipeline(MemorySource(arrivals("/a", [0.1])), [CountingObserver("/a")],
             [BrokenSink(), sink]).run(duration=3.0)
    assert len(sink.observations) == 3
    assert any(e.kind == "sink_error" and "disk on fire" in e.message for e in sink.events)


def test_diagnoser_sees_every_batch_and_its_diagnoses_reach_the_sinks() -> None:
    class FirstFaultDiagnoser:
        def __init__(self) -> None:
            self.batches = 0

        def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
            self.batches += 1
            bad = tuple(o for o in observations if o.faulty)
            return Diagnosis(now, (frozenset({"/b"}),), bad) if bad else None

    diagnoser = FirstFaultDiagnoser()
    sink = CollectingSink()
    Pipeline(MemorySource(arrivals("/a", [0.1])), [CountingObserver("/a"), CountingObserver("/b")],
             [sink], diagnoser=diagnoser).run(duration=2.0)
    assert diagnoser.batches == 2
    assert len(sink.diagnoses) == 2
    assert sink.diagnoses[0].candidates == (frozenset({"/b"}),)


def test_evaluate_all_runs_every_observer_now() -> None:
    a, b = CountingObserver("/a", interval=10.0), CountingObserver("/b", interval=10.0)
    pipeline = Pipeline(MemorySource(arrivals("/a", [0.1])), [a, b])
    pipeline.start()
    pipeline.step(0.5)
    result = pipeline.evaluate_all()
    assert {o.resource.topic for o in result} == {"/a", "/b"}
    assert all(o.time == 0.5 for o in result)


def test_evaluate_all_includes_the_standing_verdict_of_an_observer_reporting_at_its_own_pace(
) -> None:
    class EveryOtherTime(CountingObserver):
        calls = 0

        def evaluate(self, now: float) -> list[Observation]:
            self.calls += 1
            return super().evaluate(now) if self.calls % 2 else []

    quiet = EveryOtherTime("/b")
    pipeline = Pipeline(MemorySource(arrivals("/b", [0.1])), [quiet])
    pipeline.start()
    pipeline.step(1.0)  # first call reports
    result = pipeline.evaluate_all(1.5)  # second call reports nothing: the standing verdict
    assert [(o.resource.topic, o.time) for o in result] == [("/b", 1.0)]
