"""The robot as a diagnosis model: nodes, topics, hardware and what is observed about them.

The model comes from a tug_diagnosis YAML file (``nodes`` with ``pub_topic``/``sub_topic``,
``observations`` with ``type`` and ``nodes`` or ``topics``; an optional ``hardware`` list per
node names devices behind a driver node) or is derived from a live :class:`GraphSnapshot`
plus the observers' resources, with no extra file.

A topic fails in one of two *modes*, each with its own variable (weak fault model; see
``docs/diagnosis.md``):

* ``live(T)``: messages arrive at the right rate. It holds when the topic (the transport),
  its publishers, their hardware and those input topics whose silence silences the
  publisher (see :class:`Propagation`) are healthy and live.
* ``right(T)``: the messages carry right values. It holds when the publishers, their
  hardware and the values of their inputs are right; a transport delays or drops messages
  but does not change them, and an input's rate failure reaches the values only where
  configured (``value_from_rate``).
* *rate* observations (``hz``, ``timeout``, ``timestamp``, ``timing``) on ``T`` fail only when
  ``live`` fails for the observed publisher group, *value* observations (``scores``,
  ``velocity``, ``moving``) only when ``right`` fails; ``activated`` and ``resources`` when
  their node is faulty, ``network`` when its interface is.
* Exoneration: when the observations judging a mode of ``T`` (covering all its publishers)
  are all known and OK, that mode holds. A mode nobody judges stays open: a rate observer
  clears nobody of a value fault. A topic seen silent (a failed ``timeout``, or every
  publisher failing ``activated``) carries no values, so its value mode holds: a dead
  camera explains a silent signal, not a wrong signal value (unless ``value_from_rate``).

Topics in a feedback loop are treated as one unit (their strongly connected component), so a
cycle of healthy nodes can never "explain" a symptom by itself.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from blackbox.config.node import ConfigNode
from blackbox.events import GraphSnapshot
from blackbox.model import Resource
from blackbox.observe.base import OBSERVERS, Mode, Subject, observer_kind

RATE_MODES = ("learn", "always", "never")


def is_rate_type(observer: str) -> bool:
    """Whether observations of this type judge the rate (``live``) rather than the values.

    The observer type says so when it registers (:class:`ObserverKind` ``judges``); an
    unregistered type (a probe of the black box itself) counts as a rate observation.
    """
    kind = observer_kind(observer)
    return kind is None or kind.judges is Mode.LIVE


def is_relation_type(observer: str) -> bool:
    """Whether observations of this type relate the values of their topics (a failed one
    needs a wrong value on one of them; a held one clears each of them)."""
    kind = observer_kind(observer)
    return kind is not None and kind.relation


def exonerates(observer: str) -> bool:
    """Whether OK observations of this type clear the mode they judge when all are OK."""
    kind = observer_kind(observer)
    return kind is None or (kind.exonerates and not kind.relation)


def judges_alive(observer: str) -> bool:
    """Whether a failed observation of this type says a signal of its topic is not alive
    (stuck or noisy), which a relation of that topic may fail by (:class:`ObserverKind`
    ``judges_alive``)."""
    kind = observer_kind(observer)
    return kind is not None and kind.judges_alive


def shows_silent(observer: str) -> Subject | None:
    """What a failed observation of this type shows to send nothing: its node, its topic,
    or nothing (``None``) when its failure may have another cause (a rate that is too high,
    wrong values). The observer type says so when it registers (:class:`ObserverKind`
    ``failure_means_silent``); an unregistered type shows nothing."""
    kind = observer_kind(observer)
    return kind.subject if kind is not None and kind.failure_means_silent else None


def _subject(observer: str) -> Subject | None:
    kind = observer_kind(observer)
    return kind.subject if kind is not None else None


def observation_types() -> list[str]:
    """Every observer type a diagnosis model may name, with the aliases of tug_diagnosis."""
    return sorted({n for name, kind in OBSERVERS.items() for n in (name, *kind.aliases)})


@dataclass(frozen=True, slots=True)
class NodeSpec:
    name: str
    pub: tuple[str, ...] = ()
    sub: tuple[str, ...] = ()
    hardware: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class ObservationSpec:
    """An observed characteristic: observer type name and the resource it observes."""

    type: str
    resource: Resource

    def key(self) -> tuple[str, Resource]:
        return (self.type, self.resource)


@dataclass(frozen=True, slots=True)
class NodePropagation:
    """How faults of a node's inputs reach its outputs; ``None`` falls back to the default.

    ``rate``: ``always`` (the node stops publishing when an input falls silent), ``never``
    (it publishes on its own clock), ``learn`` (assume ``always`` until the node is seen
    publishing at rate while an input is silent). ``value_from_rate``: a silent or off-rate
    input may make the node's output values wrong (stale or default values).
    """

    rate: str | None = None
    value_from_rate: bool | None = None


@dataclass(frozen=True, slots=True)
class Propagation:
    """Fault propagation through the nodes; defaults for every node plus per-node overrides.

    ``learn_after`` is how many seconds the evidence for ``learn`` (input silent, output at
    rate) must last: a node that stops after its own input time-out looks independent
    until then.
    """

    rate: str = "learn"
    value_from_rate: bool = False
    learn_after: float = 3.0
    nodes: Mapping[str, NodePropagation] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for mode in (self.rate, *(n.rate for n in self.nodes.values() if n.rate)):
            if mode not in RATE_MODES:
                raise ValueError(f"rate propagation must be one of {', '.join(RATE_MODES)}, "
                                 f"got {mode!r}")

    def rate_of(self, node: str) -> str:
        own = self.nodes.get(node)
        return own.rate if own is not None and own.rate is not None else self.rate

    def value_from_rate_of(self, node: str) -> bool:
        own = self.nodes.get(node)
        if own is not None and own.value_from_rate is not None:
            return own.value_from_rate
        return self.value_from_rate


@dataclass(frozen=True, slots=True)
class RobotModel:
    """Components and structure. Nodes are sorted by name, observations in declared order."""

    nodes: tuple[NodeSpec, ...]
    observations: tuple[ObservationSpec, ...] = ()
    interfaces: tuple[str, ...] = field(default=())

    @property
    def topics(self) -> tuple[str, ...]:
        seen: dict[str, None] = {}
        for n in self.nodes:
            for t in (*n.pub, *n.sub):
                seen.setdefault(t)
        for o in self.observations:
            for observed in (o.resource.topic, o.resource.topic_b):
                if observed:
                    seen.setdefault(observed)
        return tuple(sorted(seen))

    @property
    def components(self) -> tuple[str, ...]:
        names = [n.name for n in self.nodes]
        names += [h for n in self.nodes for h in n.hardware]
        names += list(self.topics)
        names += [f"iface:{i}" for i in self.interfaces]
        return tuple(dict.fromkeys(names))

    def kind(self, component: str) -> str:
        """``node``, ``hardware``, ``topic`` or ``interface``."""
        if component.startswith("iface:"):
            return "interface"
        for n in self.nodes:
            if n.name == component:
                return "node"
            if component in n.hardware:
                return "hardware"
        return "topic"

    def publishers(self, topic: str) -> tuple[str, ...]:
        return tuple(n.name for n in self.nodes if topic in n.pub)

    def node(self, name: str) -> NodeSpec | None:
        return next((n for n in self.nodes if n.name == name), None)


def build_model(nodes: Iterable[NodeSpec], observations: Iterable[ObservationSpec]
               ) -> RobotModel:
    obs = tuple(dict.fromkeys(observations))
    ifaces = tuple(sorted({o.resource.interface for o in obs if o.resource.interface}))
    ns = tuple(sorted((NodeSpec(n.name, tuple(sorted(set(n.pub))), tuple(sorted(set(n.sub))),
                                tuple(n.hardware)) for n in nodes), key=lambda n: n.name))
    return RobotModel(ns, obs, ifaces)


# ---- tug_diagnosis YAML --------------------------------------------------------------------

def load_robot_model(path: str | Path) -> RobotModel:
    """Load a tug_diagnosis model file; every error names file, line and key path."""
    return parse_robot_model(ConfigNode.load(path))


def parse_robot_model(root: ConfigNode) -> RobotModel:
    root.check_keys(["nodes", "observations"])
    nodes: list[NodeSpec] = []
    names: set[str] = set()
    for item in root["nodes"].list():
        item.check_keys(["name", "pub_topic", "sub_topic", "hardware"])
        name = item["name"].str()
        if name in names:
            raise item["name"].error(f"node {name!r} defined twice")
        names.add(name)
        pub = item.get("pub_topic")
        sub = item.get("sub_topic")
        hw = item.get("hardware")
        nodes.append(NodeSpec(name, pub.str_list() if pub else (), sub.str_list() if sub else (),
                              hw.str_list() if hw else ()))
    known_topics = {t for n in nodes for t in (*n.pub, *n.sub)}
    observations: list[ObservationSpec] = []
    obs_node = root.get("observations")
    for item in obs_node.list() if obs_node else []:
        item.check_keys(["type", "nodes", "topics", "interfaces", "callerids"])
        kind = item["type"].str(observation_types())
        subject = _subject(kind)
        if subject is Subject.NODE:
            for n in item["nodes"].list(allow_single=True):
                if n.str() not in names:
                    raise n.error(f"unknown node {n.str()!r}; declare it under 'nodes'")
                observations.append(ObservationSpec(kind, Resource(node=n.str())))
        elif subject is Subject.INTERFACE:
            for i in item["interfaces"].str_list():
                observations.append(ObservationSpec(kind, Resource(interface=i)))
        else:
            topics_node = item["topics"]
            topics = topics_node.str_list()
            for t in topics:
                if t not in known_topics:
                    raise topics_node.error(f"topic {t!r} is neither published nor subscribed "
                                            f"by a declared node")
            callers = item.get("callerids")
            group = tuple(callers.str_list()) if callers else ()
            if subject is Subject.TOPIC_PAIR:
                if len(topics) != 2:
                    raise topics_node.error(f"'{kind}' observes exactly two topics, "
                                            f"got {len(topics)}")
                observations.append(ObservationSpec(
                    kind, Resource(topic=topics[0], topic_b=topics[1], publishers=group)))
            else:
                observations.extend(ObservationSpec(kind, Resource(topic=t, publishers=group))
                                    for t in topics)
    return build_model(nodes, observations)


# ---- derived from the live graph -----------------------------------------------------------

class ObservedResource(Protocol):
    """What the model needs from an observer: its type name and what it observes."""

    @property
    def type_name(self) -> str: ...

    @property
    def resource(self) -> Resource: ...


def derive_robot_model(graph: GraphSnapshot, observed: Sequence[ObservedResource]
                       ) -> RobotModel:
    """The part of the graph that can explain an observation: observed nodes and topics and
    everything upstream of the observed topics."""
    specs = [ObservationSpec(o.type_name, o.resource) for o in observed]
    pubs: dict[str, set[str]] = {}
    subs_of: dict[str, set[str]] = {}
    for info in graph.topics.values():
        for p in info.publishers:
            pubs.setdefault(info.name, set()).add(p)
        for s in info.subscribers:
            subs_of.setdefault(s, set()).add(info.name)
    topics: set[str] = set()
    producers: set[str] = set()
    stack = [t for s in specs for t in (s.resource.topic, s.resource.topic_b) if t]
    while stack:
        t = stack.pop()
        if t in topics:
            continue
        topics.add(t)
        for p in pubs.get(t, ()):
            producers.add(p)
            stack.extend(i for i in subs_of.get(p, ()) if i not in topics)
    observed_nodes = {s.resource.node for s in specs if s.resource.node}
    specs_nodes = []
    for n in sorted(producers | observed_nodes):
        pub = tuple(t for t in topics if n in pubs.get(t, ()))
        sub = tuple(t for t in subs_of.get(n, ()) if t in topics) if n in producers else ()
        specs_nodes.append(NodeSpec(n, pub, sub))
    return build_model(specs_nodes, specs)


# ---- clauses ---------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Edge:
    """``node`` publishes ``output`` and subscribes ``input``: a path for faults."""

    node: str
    output: str
    input: str


@dataclass(frozen=True, slots=True)
class Explanation:
    """Who may be to blame for an observation: ``components`` directly, ``inputs`` via the
    health of upstream topics; ``edges`` say through which node each input is reached."""

    components: tuple[str, ...]
    inputs: tuple[str, ...]
    edges: tuple[Edge, ...] = ()


def _scc(model: RobotModel) -> dict[str, frozenset[str]]:
    """Strongly connected components of the topic dependency graph (Tarjan, iterative)."""
    deps: dict[str, list[str]] = {t: [] for t in model.topics}
    for n in model.nodes:
        for t in n.pub:
            deps[t].extend(n.sub)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on: set[str] = set()
    stack: list[str] = []
    out: dict[str, frozenset[str]] = {}
    counter = 0
    for start in deps:
        if start in index:
            continue
        work = [(start, iter(deps[start]))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            advanced = False
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(deps[w])))
                    advanced = True
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                group = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    group.append(w)
                    if w == v:
                        break
                fs = frozenset(group)
                for w in group:
                    out[w] = fs
    return out


class TopicStructure:
    """Upstream explanations of every topic, with feedback loops collapsed."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self.scc = _scc(model)
        self._pub = {t: model.publishers(t) for t in model.topics}
        self._node = {n.name: n for n in model.nodes}

    def publishers(self, topic: str) -> tuple[str, ...]:
        return self._pub.get(topic, ())

    def producers(self, topic: str, group: Sequence[str] = (), rate: bool = True
                  ) -> Explanation:
        """Components and input topics that explain a fault seen on ``topic``."""
        loop = self.scc.get(topic, frozenset({topic}))
        cyclic = len(loop) > 1 or any(topic in self._node[p].sub for p in self._pub.get(topic, ())
                                      if p in self._node)
        topics = sorted(loop) if cyclic else [topic]
        comps: list[str] = []
        edges: list[Edge] = []
        for t in topics:
            pubs = self._pub.get(t, ())
            if rate or cyclic or not pubs:  # no modelled publisher: the topic stands for it
                comps.append(t)
            if group and t == topic:
                pubs = tuple(p for p in pubs if p in group) or tuple(group)
            for p in pubs:
                spec = self._node.get(p)
                comps.append(p)
                if spec is None:
                    continue
                comps.extend(spec.hardware)
                edges.extend(Edge(p, t, i) for i in spec.sub if i not in loop)
        edges = list(dict.fromkeys(edges))
        return Explanation(tuple(dict.fromkeys(comps)),
                           tuple(dict.fromkeys(e.input for e in edges)), tuple(edges))

    def explain(self, spec: ObservationSpec) -> Explanation:
        r = spec.resource
        subject = _subject(spec.type)
        if subject is Subject.NODE or (r.node and not r.topic):
            return Explanation((r.node,) if r.node else (), ())
        if subject is Subject.INTERFACE or (r.interface and not r.topic):
            return Explanation((f"iface:{r.interface}",), ())
        rate = is_rate_type(spec.type)
        parts = [self.producers(r.topic, r.publishers, rate)] if r.topic else []
        if r.topic_b:
            parts.append(self.producers(r.topic_b, (), rate))
        return Explanation(tuple(dict.fromkeys(c for p in parts for c in p.components)),
                           tuple(dict.fromkeys(i for p in parts for i in p.inputs)),
                           tuple(dict.fromkeys(e for p in parts for e in p.edges)))

    def mentions(self, spec: ObservationSpec) -> tuple[str, ...]:
        """Topics whose every aspect this observation covers (for exoneration)."""
        r = spec.resource
        if r.publishers and r.topic and set(self._pub.get(r.topic, ())) - set(r.publishers):
            return ()
        return tuple(t for t in (r.topic, r.topic_b) if t)


def observed_topics(model: RobotModel) -> Mapping[str, list[ObservationSpec]]:
    out: dict[str, list[ObservationSpec]] = {}
    s = TopicStructure(model)
    for o in model.observations:
        for t in s.mentions(o):
            out.setdefault(t, []).append(o)
    return out
