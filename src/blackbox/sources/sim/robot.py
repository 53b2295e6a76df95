"""A simulated robot that implements the Source protocol, with fault injection.

A discrete-event simulation: every topic schedules its next publication, a 1 Hz tick
samples the graph, resources and network, and faults switch on and off at their times.
``poll(until)`` runs the simulation up to ``until``; with ``realtime=True`` it first waits
for the wall clock, so the same robot can drive a live pipeline or a fast batch run.
"""

from __future__ import annotations

import heapq
import math
import random
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

from blackbox.config.node import ConfigError
from blackbox.events import (
    Event,
    GraphSnapshot,
    Interest,
    MessageArrival,
    NetworkSample,
    NodeInfo,
    ResourceSample,
    TopicInfo,
    TopicSchema,
)
from blackbox.sources.base import (
    SOURCES,
    Capabilities,
    RandomFaults,
    SourceKind,
    SourceOptions,
)

from .faults import FAULT_KINDS, Fault, GroundTruth, load_faults, random_campaign
from .messages import ScalarModel, TopicMessages, scalars_of
from .motion import Motion
from .topology import NodeSpec, TopicSpec, Topology

TICK = 1.0
# Order of simultaneous events: faults switch first, then the tick, then messages.
_FAULT, _TICK, _PUBLISH = 0, 1, 2


@dataclass(slots=True)
class _NodeState:
    spec: NodeSpec
    pid: int
    rng: random.Random
    started: float
    kills: int = 0
    hogs: list[Fault] = field(default_factory=list)
    growths: list[Fault] = field(default_factory=list)

    @property
    def alive(self) -> bool:
        return self.kills == 0


@dataclass(slots=True)
class _TopicState:
    spec: TopicSpec
    messages: TopicMessages
    timing: random.Random
    values: random.Random
    fault_noise: random.Random
    generation: int = 0
    seq: int = 0
    last_publish: float | None = None
    last_value: tuple[float, ...] | None = None
    stalls: int = 0
    rate_faults: list[Fault] = field(default_factory=list)
    value_faults: list[tuple[Fault, tuple[float, ...]]] = field(default_factory=list)
    scalars: tuple[ScalarModel, ...] = ()

    def rate(self) -> float:
        rate = self.spec.rate
        for f in self.rate_faults:
            rate = f.params["hz"] if "hz" in f.params else rate * f.params["factor"]
        return rate


class _LazyMessage:
    """Builds the message on first use; serializes it only when raw bytes are asked for."""

    __slots__ = ("_msg", "messages", "seq", "time", "value")

    def __init__(self, messages: TopicMessages, seq: int, time: float,
                 value: tuple[float, ...] | None):
        self.messages = messages
        self.seq = seq
        self.time = time
        self.value = value
        self._msg: Any = None

    def decode(self) -> Any:
        if self._msg is None:
            self._msg = self.messages.message(self.seq, self.time, self.value)
        return self._msg

    def raw(self) -> bytes:
        return self.messages.serialize(self.decode())


SIM_CAPABILITIES = Capabilities(simulated_clock=True, fault_injection=True, ground_truth=True,
                                snapshot_format="mcap")


class SimulatedSource:
    """The robot of a :class:`Topology`, with ``faults`` injected, as a Source.

    Same ``seed``, topology and faults give the same events. ``start_time`` is the clock
    value at the start (use ``time.time()`` for wall-clock stamps; it must be >= 0 because
    ROS 1 stamps are unsigned).
    """

    def __init__(self, topology: Topology, faults: Iterable[Fault] = (), seed: int = 0,
                 realtime: bool = False, start_time: float = 0.0,
                 name: str | None = None) -> None:
        if not start_time >= 0:
            raise ValueError(f"start_time must be >= 0, got {start_time!r}")
        self.topology = topology
        self.faults = tuple(sorted(faults, key=lambda f: f.start))
        for f in self.faults:
            f.check(topology)
        self.seed = seed
        self.realtime = realtime
        self.start_time = float(start_time)
        self.name = name or f"sim:{topology.name}"
        self.capabilities = SIM_CAPABILITIES
        self._interest = Interest()
        self._arrivals: frozenset[str] = frozenset()
        self._started = False
        self._closed = False
        self._clock = self.start_time
        self._wall_origin = 0.0
        self._heap: list[tuple[float, int, int, str, Any]] = []
        self._order = 0
        self._truth: dict[int, GroundTruth] = {}
        self._last_graph: float | None = None
        self._tx = 0
        self._rx = 0
        self._next_pid = max((n.pid for n in topology.nodes.values()), default=1000) + 1
        self._topic_infos = MappingProxyType({
            t.name: TopicInfo(t.name, t.type, (t.publisher,), t.subscribers)
            for t in topology.topics.values()})
        self._nodes = {
            n.name: _NodeState(n, n.pid, self._rng("resources", n.name), self.start_time)
            for n in topology.nodes.values()}
        self._topics = {
            t.name: _TopicState(t, TopicMessages(topology.store, t.type, t.value, t.frame_id),
                                self._rng("timing", t.name), self._rng("values", t.name),
                                self._rng("fault_noise", t.name),
                                scalars=scalars_of(t.value))
            for t in topology.topics.values()}
        self.motion = Motion(topology.motion, topology.modes, seed)
        """The robot's motion in this run (``motion.schedule.mode_at(t)``: its operating mode
        ``t`` seconds after the start, the ground truth of "standing, driving, turning")."""
        self._last_heard = {t: self.start_time for t in topology.topics}

    def _rng(self, stream: str, component: str) -> random.Random:
        # One generator per stream and component: a fault on one topic never shifts the
        # random numbers of another.
        return random.Random(f"blackbox-sim:{self.seed}:{stream}:{component}")

    # ---- Source protocol -------------------------------------------------------------------

    def start(self, interest: Interest) -> None:
        if self._started:
            raise RuntimeError(f"{self.name} was already started")
        self._started = True
        self._interest = interest
        self._arrivals = frozenset(interest.topics | interest.decoded)
        t0 = self.start_time
        self._push(t0, _TICK, "tick", None)
        for i, f in enumerate(self.faults):
            self._push(self.start_time + f.start, _FAULT, "fault_start", i)
            if f.end is not None:
                self._push(self.start_time + f.end, _FAULT, "fault_end", i)
        for state in self._topics.values():
            self._schedule_first(state, t0)
        self._wall_origin = time.monotonic()

    def now(self) -> float:
        if self.realtime and self._started:
            return self.start_time + (time.monotonic() - self._wall_origin)
        return self._clock

    def poll(self, until: float) -> list[Event]:
        if not self._started:
            raise RuntimeError(f"{self.name}: call start() before poll()")
        if self._closed:
            return []
        if not math.isfinite(until):
            raise ValueError(f"{self.name}: poll needs a finite time, got {until!r}")
        if self.realtime:
            while (wait := until - self.now()) > 0:
                time.sleep(wait)
        events: list[Event] = []
        heap = self._heap
        while heap and heap[0][0] <= until:
            t, _, _, action, arg = heapq.heappop(heap)
            if action == "publish":
                self._publish(t, arg, events)
            elif action == "tick":
                self._tick(t, events)
            elif action == "fault_start":
                self._fault_start(t, arg, events)
            else:
                self._fault_end(t, arg, events)
        self._clock = max(self._clock, until)
        return events

    def schema(self, topic: str) -> TopicSchema | None:
        state = self._topics.get(topic)
        if state is None:
            return None
        definition, md5 = state.messages.definition()
        return TopicSchema(topic, state.spec.type, "ros1", definition, md5)

    def close(self) -> None:
        self._closed = True
        self._heap.clear()

    # ---- ground truth ----------------------------------------------------------------------

    def topic_publishers(self) -> dict[str, str]:
        return {t.name: t.publisher for t in self.topology.topics.values()}

    @property
    def ground_truth(self) -> list[GroundTruth]:
        """Every fault injected so far, in start order, with times on this source's clock
        (``start_time`` + the fault's offsets); ``end`` is ``None`` while still active."""
        return [self._truth[i] for i in sorted(self._truth)]

    # ---- simulation --------------------------------------------------------------------------

    def _push(self, t: float, order: int, action: str, arg: Any) -> None:
        self._order += 1
        heapq.heappush(self._heap, (t, order, self._order, action, arg))

    def _schedule_first(self, state: _TopicState, t: float) -> None:
        """A (re)started stream begins at a random phase within one period."""
        state.generation += 1
        self._push(t + state.timing.random() / state.rate(), _PUBLISH, "publish",
                   (state.spec.name, state.generation))

    def _schedule_next(self, state: _TopicState, t: float) -> None:
        period = 1.0 / state.rate()
        step = period + state.timing.gauss(0.0, state.spec.jitter) if state.spec.jitter else period
        self._push(t + max(step, 0.5 * period), _PUBLISH, "publish",
                   (state.spec.name, state.generation))

    def _can_publish(self, state: _TopicState) -> bool:
        return state.stalls == 0 and self._nodes[state.spec.publisher].alive

    def _publish(self, t: float, arg: tuple[str, int], events: list[Event]) -> None:
        name, generation = arg
        state = self._topics[name]
        if generation != state.generation or not self._can_publish(state):
            return
        self._schedule_next(state, t)
        node = self._nodes[state.spec.publisher].spec
        if node.requires and any(t - self._last_heard[r] > node.requires_timeout
                                 for r in node.requires):
            return
        value = self._value(state, t)
        state.seq += 1
        state.last_publish = t
        state.last_value = value
        self._last_heard[name] = t
        size = state.messages.size
        self._tx += size
        self._rx += size * sum(1 for s in state.spec.subscribers if self._nodes[s].alive)
        if name in self._arrivals:
            lazy = _LazyMessage(state.messages, state.seq, t, value)
            events.append(MessageArrival(t, name, state.spec.publisher, size,
                                         decode=lazy.decode, raw=lazy.raw))

    def _value(self, state: _TopicState, t: float) -> tuple[float, ...] | None:
        if not state.scalars:
            return None
        elapsed = t - self.start_time
        out: list[float] = []
        for k, model in enumerate(state.scalars):
            if model.distribution == "gauss":
                value = model.mean + state.values.gauss(0.0, model.noise)
            else:
                value = model.mean + state.values.uniform(-model.noise, model.noise)
            for signal, gain in model.follows:
                value += gain * self.motion.at(signal, elapsed - model.lag)
            for fault, frozen in state.value_faults:
                if not fault.acts_on(model.field):
                    continue
                if fault.kind == "offset":
                    value += fault.params["value"]
                elif fault.kind == "scale":
                    value *= fault.params["factor"]
                elif fault.kind == "drift":
                    value += fault.params["rate"] * (elapsed - fault.start)
                elif fault.kind == "noise":
                    # Its own generator: the healthy values after the fault are those of
                    # the fault-free run with the same seed.
                    value += state.fault_noise.gauss(0.0, fault.params["sigma"])
                else:
                    value = frozen[k]
            out.append(value)
        return tuple(out)

    def _tick(self, t: float, events: list[Event]) -> None:
        self._push(t + TICK, _TICK, "tick", None)
        if self._last_graph != t:
            events.append(self._graph(t))
        wanted = self._interest.resources
        for node in self._nodes.values():
            sample = self._resources(node, t)
            if node.spec.name in wanted:
                events.append(sample)
        if self._interest.network:
            events.append(NetworkSample(t, self.topology.interface, self._rx, self._tx))

    def _graph(self, t: float) -> GraphSnapshot:
        self._last_graph = t
        nodes = {n.spec.name: NodeInfo(n.spec.name, n.alive, n.pid if n.alive else None)
                 for n in self._nodes.values()}
        return GraphSnapshot(t, MappingProxyType(nodes), self._topic_infos)

    def _resources(self, node: _NodeState, t: float) -> ResourceSample:
        spec = node.spec
        cpu_noise = node.rng.uniform(-spec.cpu_noise, spec.cpu_noise)
        mem_noise = node.rng.uniform(-spec.memory_noise, spec.memory_noise)
        if not node.alive:
            return ResourceSample(t, spec.name, None, None, f"process of {spec.name} is gone")
        cpu = node.hogs[-1].params["percent"] if node.hogs else spec.cpu
        memory = spec.memory + mem_noise
        for f in node.growths:
            memory += f.params["rate"] * (t - max(self.start_time + f.start, node.started))
        return ResourceSample(t, spec.name, max(cpu + cpu_noise, 0.0), max(memory, 0.0))

    # ---- faults ------------------------------------------------------------------------------

    def _fault_start(self, t: float, index: int, events: list[Event]) -> None:
        fault = self.faults[index]
        self._truth[index] = GroundTruth(t, None, fault.kind, fault.component,
                                         fault.node(self.topology), dict(fault.params),
                                         fault.field)
        kind = fault.kind
        if kind == "kill":
            node = self._nodes[fault.component]
            was_alive = node.alive
            node.kills += 1
            if was_alive:
                for topic in self.topology.published_by(node.spec.name):
                    self._topics[topic].generation += 1
                events.append(self._graph(t))
        elif kind == "cpu_hog":
            self._nodes[fault.component].hogs.append(fault)
        elif kind == "memory_growth":
            self._nodes[fault.component].growths.append(fault)
        else:
            state = self._topics[fault.component]
            if kind == "stall":
                state.stalls += 1
                state.generation += 1
            elif kind == "rate":
                state.rate_faults.append(fault)
                self._reschedule(state, t)
            else:
                frozen = state.last_value
                if frozen is None:
                    frozen = tuple(s.mean for s in state.scalars)
                state.value_faults.append((fault, frozen))

    def _fault_end(self, t: float, index: int, events: list[Event]) -> None:
        fault = self.faults[index]
        self._truth[index] = replace(self._truth[index], end=t)
        kind = fault.kind
        if kind == "kill":
            node = self._nodes[fault.component]
            node.kills -= 1
            if node.alive:
                node.pid = self._next_pid
                self._next_pid += 1
                node.started = t
                for topic in self.topology.published_by(node.spec.name):
                    state = self._topics[topic]
                    if self._can_publish(state):
                        self._schedule_first(state, t)
                events.append(self._graph(t))
        elif kind == "cpu_hog":
            self._nodes[fault.component].hogs.remove(fault)
        elif kind == "memory_growth":
            self._nodes[fault.component].growths.remove(fault)
        else:
            state = self._topics[fault.component]
            if kind == "stall":
                state.stalls -= 1
                if self._can_publish(state):
                    self._schedule_first(state, t)
            elif kind == "rate":
                state.rate_faults.remove(fault)
                self._reschedule(state, t)
            else:
                state.value_faults = [(f, v) for f, v in state.value_faults if f is not fault]

    def _reschedule(self, state: _TopicState, t: float) -> None:
        """A new rate applies from the last message: the pending one moves."""
        if not self._can_publish(state):
            return
        if state.last_publish is None:
            self._schedule_first(state, t)
            return
        state.generation += 1
        nxt = max(t, state.last_publish + 1.0 / state.rate())
        self._push(nxt, _PUBLISH, "publish", (state.spec.name, state.generation))


# ---- URIs --------------------------------------------------------------------------------------

BUILTIN_ROBOTS: Mapping[str, Path] = MappingProxyType({
    "thesis": Path(__file__).with_name("thesis.yaml"),
    "diffdrive": Path(__file__).with_name("diffdrive.yaml"),
    "skidsteer": Path(__file__).with_name("skidsteer.yaml"),
})


def open_sim(spec: str, *, faults: str | Path | Iterable[Fault] | None = None,
             seed: int | None = None, realtime: bool | None = None,
             start_time: float | None = None) -> SimulatedSource:
    """A simulated robot from a source URI.

    ``sim:thesis`` is the shipped thesis robot, ``sim:/path/robot.yaml`` a topology file.
    Options may follow as a query (``sim:thesis?faults=f.yaml&seed=3&realtime=1``);
    keyword arguments win over the query. ``faults`` is a fault YAML file or Faults.
    Raises ``ValueError`` (unknown robot, bad option) or ``ConfigError`` (bad YAML).
    """
    body = spec.removeprefix("sim:")
    query: dict[str, str] = {}
    head, sep, tail = body.rpartition("?")
    if sep and "=" in tail:
        body = head
        for part in tail.split("&"):
            key, eq, value = part.partition("=")
            if not eq or key not in ("faults", "seed", "realtime", "start_time"):
                raise ValueError(f"{spec}: unknown option {part!r} "
                                 "(allowed: faults, seed, realtime, start_time)")
            query[key] = value
    if not body:
        raise ValueError(f"{spec}: name a robot, e.g. sim:thesis or sim:/path/robot.yaml")
    if body in BUILTIN_ROBOTS:
        path = BUILTIN_ROBOTS[body]
    elif "/" in body or body.endswith((".yaml", ".yml")):
        path = Path(body)
    else:
        raise ValueError(f"{spec}: unknown built-in robot {body!r}; built-in: "
                         f"{', '.join(BUILTIN_ROBOTS)}, or give a topology YAML path")
    topology = Topology.load(path)
    try:
        if seed is None:
            seed = int(query.get("seed", "0"))
        if realtime is None:
            realtime = query.get("realtime", "0").lower() in ("1", "true", "yes")
        if start_time is None:
            start_time = float(query.get("start_time", "0"))
    except ValueError as exc:
        raise ValueError(f"{spec}: bad option value: {exc}") from None
    if faults is None and "faults" in query:
        faults = query["faults"]
    if isinstance(faults, str | Path):
        fault_list = load_faults(faults, topology)
    else:
        fault_list = list(faults or ())
    name = f"sim:{body}" if body in BUILTIN_ROBOTS else f"sim:{topology.name}"
    return SimulatedSource(topology, fault_list, seed=seed, realtime=realtime,
                           start_time=start_time, name=name)


def open_sim_source(spec: str, options: SourceOptions) -> SimulatedSource:
    """``open_sim`` with typed options; a :class:`RandomFaults` plan is drawn on the robot's
    topology with the options' seed."""
    start = options.start_time
    if start is None:
        # A real-time robot stamps with the wall clock, so its records line up with
        # everything else on the machine; a simulated clock starts at 0, reproducibly.
        start = time.time() if options.realtime else 0.0
    plan = options.faults
    try:
        source = open_sim(spec, faults=None if isinstance(plan, RandomFaults) else plan,
                          seed=options.seed, realtime=options.realtime, start_time=start)
    except ValueError as exc:
        raise ConfigError(str(exc), "--source") from None
    if not isinstance(plan, RandomFaults):
        return source
    faults = random_campaign(source.topology, plan.horizon, options.seed,
                             plan.kinds or tuple(FAULT_KINDS), mean_gap=plan.mean_gap,
                             warmup=plan.warmup, min_separation=plan.min_separation)
    return SimulatedSource(source.topology, faults, seed=options.seed, realtime=options.realtime,
                           start_time=start, name=source.name)


SOURCES.add("sim", SourceKind("sim", open_sim_source, SIM_CAPABILITIES, "sim:thesis or sim:FILE"))
