"""The black box's main loop: source events -> observers -> diagnosis -> sinks.

One thread, one direction. The pipeline asks the source for every event up to the next
evaluation time, hands each event to the observers interested in it, evaluates the
observers that are due, passes the observations to the diagnosis engine and everything to
the sinks. Nothing here reads a clock: the source's ``poll`` decides whether time is
simulated or real.

A :class:`~blackbox.events.MeasurementGap` goes to the observers of what it names (every
observer for a gap of everything) and to the sinks as a black-box event saying "not
measured from ... to ..."; after a gap of everything the evaluations restart at its end
instead of catching up on times the black box did not see.

A failing observer or sink is isolated: the error becomes a black-box event and the loop
goes on, because the black box must keep watching whatever else breaks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import heapq
import threading
import traceback
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, cast

from blackbox.events import (
    ArrivalBatch,
    Event,
    GraphSnapshot,
    Interest,
    MeasurementGap,
    MessageArrival,
    NetworkSample,
    ResourceSample,
    merge_interests,
)
from blackbox.model import BlackBoxEvent, Code, Diagnosis, Observation, Resource
from blackbox.observe.base import Observer
from blackbox.observe.gaps import describe_gap
from blackbox.sinks import Sink
from blackbox.sources.base import ReplaySource, Source


class Diagnoser(Protocol):
    """What the pipeline needs from a diagnosis engine. A diagnoser that also has
    ``on_graph(graph)`` receives every graph snapshot (to follow the robot's structure)."""

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None: ...


@dataclass(slots=True)
class RunStats:
    """Counters of one run, for the closing summary and the benchmarks."""

    started: float = 0.0
    ended: float = 0.0
    messages: int = 0
    graphs: int = 0
    samples: int = 0
    evaluations: int = 0
    observations: int = 0
    faulty_observations: int = 0
    diagnoses: int = 0
    errors: int = 0


class Pipeline:
    """Runs observers over a source and fans the results out to sinks."""

    def __init__(
        self,
        source: Source,
        observers: Sequence[Observer],
        sinks: Sequence[Sink] = (),
        diagnoser: Diagnoser | None = None,
    ) -> None:
        self.source = source
        self.observers = list(observers)
        self.sinks = list(sinks)
        self.diagnoser = diagnoser
        self.stats = RunStats()
        self._by_topic: dict[str, list[Callable[[MessageArrival], None]]] = defaultdict(list)
        self._batches_by_topic: dict[str, list[Callable[[ArrivalBatch], None]]] = \
            defaultdict(list)
        self._by_node_resources: dict[str, list[Observer]] = defaultdict(list)
        self._gaps_by_topic: dict[str, list[Observer]] = defaultdict(list)
        self._gaps_by_node: dict[str, list[Observer]] = defaultdict(list)
        self._network: list[Observer] = []
        self._graph: list[Observer] = []
        self._message_sinks = [s for s in self.sinks if getattr(s, "wants_messages", False)]
        self._queue: list[tuple[float, int]] = []
        self._reported: set[tuple[str, str]] = set()
        self._restart_at: float | None = None
        self._started = False
        self._closed = False
        self._interest = Interest()
        self._latest: dict[int, list[Observation]] = {}
        self.latest_graph: GraphSnapshot | None = None
        # Re-entrant: an imported configuration is applied from inside a sink call of step().
        self.lock = threading.RLock()
        self._index_observers()

    def _index_observers(self) -> None:
        self._by_topic.clear()
        self._batches_by_topic.clear()
        self._by_node_resources.clear()
        self._gaps_by_topic.clear()
        self._gaps_by_node.clear()
        self._network = []
        self._graph = []
        for obs in self.observers:
            interest = obs.interest()
            on_batch = _batch_handler(obs)
            for topic in interest.topics | interest.decoded:
                self._by_topic[topic].append(obs.on_message)
                self._batches_by_topic[topic].append(on_batch)
            for topic in interest.topics | interest.decoded:
                self._gaps_by_topic[topic].append(obs)
            for node in interest.resources:
                self._by_node_resources[node].append(obs)
            for node in interest.nodes | interest.resources:
                self._gaps_by_node[node].append(obs)
            if interest.network:
                self._network.append(obs)
            self._graph.append(obs)

    def replace_observers(self, observers: Sequence[Observer]) -> None:
        """Swap in a new set of observers without a restart (an imported configuration).

        The source keeps what it was asked for at start, so the new observers may only need
        topics, nodes and data the running source already delivers; otherwise this raises
        ``ValueError`` naming what would need a restart.
        """
        new = merge_interests(o.interest() for o in observers)
        old = self._interest
        missing = sorted((new.topics - old.topics) | (new.decoded - old.decoded)
                         | (new.resources - old.resources))
        if missing or (new.network and not old.network):
            raise ValueError("the new configuration needs data the running source does not "
                             f"deliver ({', '.join(missing) or 'network'}); restart to apply")
        with self.lock:
            now = self.source.now()
            self.observers = list(observers)
            self._index_observers()
            self._queue = [(now + o.interval, i) for i, o in enumerate(self.observers)]
            heapq.heapify(self._queue)
            if self.latest_graph is not None:
                for obs in self._graph:
                    obs.on_graph(self.latest_graph)
            retarget = getattr(self.diagnoser, "replace_observers", None)
            if retarget is not None:
                retarget(self.observers, self.latest_graph)

    # ---- lifecycle -------------------------------------------------------------------------

    def start(self) -> None:
        if self._started:
            return
        self._started = True
        interest = dataclasses.replace(merge_interests(o.interest() for o in self.observers),
                                       arrival_batches=True)
        self._interest = interest
        self.source.start(interest)
        now = self.source.now()
        self.stats.started = now
        self._queue = [(now + o.interval, i) for i, o in enumerate(self.observers)]
        heapq.heapify(self._queue)
        self._emit_event(BlackBoxEvent(now, "start", f"black box started on {self.source.name} "
                                       f"with {len(self.observers)} observers"))

    def run(self, duration: float | None = None, stop: threading.Event | None = None) -> RunStats:
        """Run until ``duration`` seconds of source time have passed, ``stop`` is set or a
        recording (a ``replay`` source) has run out."""
        self.start()
        end = None if duration is None else self.stats.started + duration
        replay = self.source.capabilities.replay
        tick = 1.0
        try:
            while not (stop is not None and stop.is_set()):
                until = self._queue[0][0] if self._queue else self.source.now() + tick
                if end is not None and until > end:
                    until = end
                self.step(until)
                if end is not None and until >= end:
                    break
                if replay and cast(ReplaySource, self.source).exhausted():
                    break
        finally:
            self.close()
        return self.stats

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        now = self.source.now() if self._started else 0.0
        self.stats.ended = now
        self._emit_event(BlackBoxEvent(now, "stop", "black box stopped"))
        for sink in self.sinks:
            try:
                sink.close()
            except Exception as exc:
                self._report_error("sink", type(sink).__name__, exc, now, emit=False)
        try:
            self.source.close()
        except Exception as exc:
            self._report_error("source", self.source.name, exc, now, emit=False)

    # ---- one step --------------------------------------------------------------------------

    def step(self, until: float) -> list[Observation]:
        """Dispatch all events up to ``until`` and evaluate the observers due by then."""
        events = self.source.poll(until)
        with self.lock:
            self._restart_at = None
            self._dispatch(events)
            restart = self._restart()
            if restart is not None:  # a clock stepped back: ``until`` is stale
                until = min(until, restart)
            observations: list[Observation] = []
            while self._queue and self._queue[0][0] <= until:
                due, index = heapq.heappop(self._queue)
                observer = self.observers[index]
                observations.extend(self._evaluate(observer, due))
                heapq.heappush(self._queue, (due + observer.interval, index))
            if observations:
                self._publish(until, observations)
        return observations

    def evaluate_all(self, now: float | None = None) -> list[Observation]:
        """Evaluate every observer now (initiated built-in test); does not reschedule.

        Safe to call from another thread (the DDS run_IBIT service): it waits for the
        current step to finish."""
        t = self.source.now() if now is None else now
        with self.lock:
            result: list[Observation] = []
            for observer in self.observers:
                fresh = self._evaluate(observer, t)
                # An observer that reports only at its own cadence (timeout) answers with
                # its standing verdict, so the test covers every observer.
                result.extend(fresh or self._latest.get(id(observer), ()))
            return result

    # ---- internals ---------------------------------------------------------------------------

    def _dispatch(self, events: list[Event]) -> None:
        by_topic = self._by_topic
        batches_by_topic = self._batches_by_topic
        message_sinks = self._message_sinks
        stats = self.stats
        i = 0
        n = len(events)
        while i < n:
            try:
                while i < n:
                    event = events[i]
                    i += 1
                    if type(event) is MessageArrival:
                        stats.messages += 1
                        for handler in by_topic.get(event.topic, ()):
                            handler(event)
                        for sink in message_sinks:
                            sink.on_message(event)
                    elif type(event) is ArrivalBatch:
                        stats.messages += event.count
                        for on_batch in batches_by_topic.get(event.topic, ()):
                            on_batch(event)
                        if message_sinks:
                            for arrival in event.arrivals():
                                for sink in message_sinks:
                                    sink.on_message(arrival)
                    elif type(event) is GraphSnapshot:
                        stats.graphs += 1
                        self._on_graph(event)
                    elif type(event) is ResourceSample:
                        stats.samples += 1
                        for obs in self._by_node_resources.get(event.node, ()):
                            obs.on_resources(event)
                    elif type(event) is NetworkSample:
                        stats.samples += 1
                        for obs in self._network:
                            obs.on_network(event)
                    elif type(event) is MeasurementGap:
                        self._on_gap(event)
                    elif isinstance(event, BlackBoxEvent):
                        self._emit_event(event)
            except Exception as exc:
                bad = events[i - 1]
                where = (getattr(bad, "topic", None) or getattr(bad, "node", None)
                         or type(bad).__name__)
                self._report_error("event", str(where), exc, getattr(bad, "time", 0.0))

    def _restart(self) -> float | None:
        """The end of a gap of everything the last dispatch met (evaluations restart there)."""
        return self._restart_at

    def _on_gap(self, gap: MeasurementGap) -> None:
        """Tell the observers of what ``gap`` names and the sinks; after a gap of everything,
        evaluate from its end on (no catching up on times nobody measured)."""
        if gap.everything:
            affected: list[Observer] = self.observers
        elif gap.topic is not None:
            affected = self._gaps_by_topic.get(gap.topic, [])
        elif gap.node is not None:
            affected = self._gaps_by_node.get(gap.node, [])
        else:
            affected = []
        for obs in affected:
            obs.on_gap(gap)
        if gap.everything and gap.end is not None:
            self._restart_at = gap.end
            self._queue = [(gap.end + o.interval, i) for i, o in enumerate(self.observers)]
            heapq.heapify(self._queue)
        component = gap.topic or gap.node or "blackbox"
        kind = "not_measured" if gap.end is None else "measured_again"
        self._emit_event(BlackBoxEvent(gap.time, kind, describe_gap(gap), component))

    def _on_graph(self, graph: GraphSnapshot) -> None:
        self.latest_graph = graph
        for obs in self._graph:
            obs.on_graph(graph)
        on_graph = getattr(self.diagnoser, "on_graph", None)
        if on_graph is not None:
            try:
                on_graph(graph)
            except Exception as exc:
                self._report_error("diagnosis", type(self.diagnoser).__name__, exc, graph.time)

    def _evaluate(self, observer: Observer, now: float) -> list[Observation]:
        self.stats.evaluations += 1
        try:
            observations = observer.evaluate(now)
            if observations:
                self._latest[id(observer)] = observations
            return observations
        except Exception as exc:
            self._report_error("observer", observer.describe(), exc, now)
            return [Observation(now, observer.type_name, Resource(), Code.GENERAL_ERROR,
                                message=f"observer failed: {exc}")]

    def _publish(self, now: float, observations: list[Observation]) -> None:
        self.stats.observations += len(observations)
        self.stats.faulty_observations += sum(1 for o in observations if o.code < 0)
        for sink in self.sinks:
            self._call(sink, "on_observations", now, observations)
        if self.diagnoser is not None:
            try:
                diagnosis = self.diagnoser.update(now, observations)
            except Exception as exc:
                self._report_error("diagnosis", type(self.diagnoser).__name__, exc, now)
                diagnosis = None
            if diagnosis is not None:
                self.stats.diagnoses += 1
                for sink in self.sinks:
                    self._call(sink, "on_diagnosis", diagnosis)

    def emit_event(self, event: BlackBoxEvent) -> None:
        """Hand one of the black box's own events to every sink (pipeline thread only)."""
        self._emit_event(event)

    def _emit_event(self, event: BlackBoxEvent) -> None:
        for sink in self.sinks:
            self._call(sink, "on_event", event)

    def _call(self, sink: Sink, method: str, *args: object) -> None:
        try:
            getattr(sink, method)(*args)
        except Exception as exc:
            self._report_error("sink", type(sink).__name__, exc, self.source.now(), emit=False)

    def _report_error(self, what: str, name: str, exc: BaseException, now: float,
                      emit: bool = True) -> None:
        self.stats.errors += 1
        key = (what, name)
        if key in self._reported:
            return
        self._reported.add(key)
        detail = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        event = BlackBoxEvent(now, f"{what}_error", f"{what} {name} failed: {detail}")
        if emit:
            self._emit_event(event)
        else:
            for sink in self.sinks:
                with contextlib.suppress(Exception):
                    sink.on_event(event)


def _batch_handler(observer: Observer) -> Callable[[ArrivalBatch], None]:
    """``observer.on_batch`` if it declares one, else its ``on_message`` per arrival."""
    on_batch: Callable[[ArrivalBatch], None] | None = getattr(observer, "on_batch", None)
    if on_batch is not None:
        return on_batch
    on_message = observer.on_message

    def expand(batch: ArrivalBatch) -> None:
        for arrival in batch.arrivals():
            on_message(arrival)

    return expand
