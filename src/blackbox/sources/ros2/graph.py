"""The ROS 2 graph rebuilt from DDS discovery, without joining it as a node.

DDS announces every participant, writer and reader on builtin topics; ROS 2 adds one
topic of its own, ``ros_discovery_info``, on which each participant lists its nodes and
the gids of their writers and readers. Joining the two gives what ``ros2 node list`` and
``ros2 topic info -v`` show: nodes, topics (``rt/x`` is ROS topic ``/x``), their types
(``pkg::msg::dds_::T_`` is ``pkg/msg/T``), each endpoint's node and QoS.

:class:`Ros2Graph` only keeps state: the source feeds it discovery samples and process
liveness and asks it for snapshots. A node is alive while a live participant lists it;
a participant dies when DDS disposes it (clean exit or lease expiry) or, for a process on
this machine, as soon as its process is gone or stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from blackbox.events import GraphSnapshot, NodeInfo, TopicInfo
from blackbox.sources.ros2.idl import ros_type_name
from blackbox.sources.ros2.qos import EndpointQos, incompatibilities

__all__ = ["Endpoint", "Participant", "Ros2Graph", "ros_topic_name"]


def ros_topic_name(dds_topic: str) -> str | None:
    """``rt/chatter`` -> ``/chatter``; ``None`` for services (``rq/``, ``rr/``) and non-ROS
    topics."""
    return "/" + dds_topic[3:] if dds_topic.startswith("rt/") else None


@dataclass(slots=True)
class Participant:
    """One DDS participant (a ROS 2 process or context). ``pid``/``host`` come from the
    properties Fast DDS (``fastdds.physical_data.*``) or Cyclone (``__Pid``) announce."""

    guid: str
    alive: bool = True
    pid: int | None = None
    host: str | None = None
    local: bool = False
    nodes: tuple[str, ...] = ()
    why_dead: str = ""
    first_seen: float = 0.0
    ros: bool = False
    """It announced a ROS 2 enclave (``enclave=`` user data), so it will list its nodes."""


@dataclass(frozen=True, slots=True)
class Endpoint:
    guid: str
    participant: str
    writer: bool
    dds_topic: str
    dds_type: str
    qos: EndpointQos

    @property
    def topic(self) -> str | None:
        return ros_topic_name(self.dds_topic)

    @property
    def type(self) -> str:
        return ros_type_name(self.dds_type) or self.dds_type


@dataclass
class Ros2Graph:
    """Participants, endpoints and nodes of one domain, as last discovered."""

    own_participants: set[str] = field(default_factory=set)
    participants: dict[str, Participant] = field(default_factory=dict)
    endpoints: dict[str, Endpoint] = field(default_factory=dict)
    node_of_endpoint: dict[str, str] = field(default_factory=dict)
    known_nodes: dict[str, str] = field(default_factory=dict)
    """Every node ever seen -> the participant that last listed it."""

    # ---- updates ---------------------------------------------------------------------------

    def participant_seen(self, guid: str, pid: int | None, host: str | None,
                         local: bool, now: float, ros: bool = False) -> Participant | None:
        if guid in self.own_participants:
            return None
        p = self.participants.get(guid)
        if p is None or p.pid is None:
            nodes = p.nodes if p is not None else ()
            p = self.participants[guid] = Participant(guid, True, pid, host, local, nodes,
                                                      first_seen=now, ros=ros)
        return p

    def unnamed(self) -> list[Participant]:
        """Live ROS 2 participants that have not yet said which nodes they hold."""
        return [p for p in self.participants.values() if p.ros and p.alive and not p.nodes]

    def participant_gone(self, guid: str, why: str) -> None:
        p = self.participants.get(guid)
        if p is not None and p.alive:
            p.alive = False
            p.why_dead = why
        for g in [g for g, e in self.endpoints.items() if e.participant == guid]:
            del self.endpoints[g]

    def endpoint_seen(self, endpoint: Endpoint) -> bool:
        """Record ``endpoint``; ``True`` if it is new (and of a live, foreign participant)."""
        if endpoint.participant in self.own_participants:
            return False
        p = self.participants.get(endpoint.participant)
        if p is not None and not p.alive:
            return False
        new = endpoint.guid not in self.endpoints
        self.endpoints[endpoint.guid] = endpoint
        return new

    def endpoint_gone(self, guid: str) -> None:
        self.endpoints.pop(guid, None)

    def nodes_listed(self, participant: str, nodes: list[tuple[str, list[str], list[str]]]
                     ) -> None:
        """``ros_discovery_info`` of ``participant``: (node name, reader gids, writer gids)."""
        if participant in self.own_participants:
            return
        p = self.participants.setdefault(participant, Participant(participant))
        for g in [g for g, n in self.node_of_endpoint.items()
                  if self.known_nodes.get(n) == participant]:
            del self.node_of_endpoint[g]
        names = []
        for name, readers, writers in nodes:
            names.append(name)
            self.known_nodes[name] = participant
            for g in (*readers, *writers):
                self.node_of_endpoint[g] = name
        p.nodes = tuple(names)

    # ---- queries ---------------------------------------------------------------------------

    def ros_participants(self) -> list[str]:
        """Participants that list nodes or have ROS topic endpoints."""
        found = {g for g, p in self.participants.items() if p.nodes}
        found.update(e.participant for e in self.endpoints.values() if e.topic is not None)
        return sorted(found)

    def publisher_name(self, writer_guid: str, now: float = float("inf"),
                       grace: float = 0.0) -> str | None:
        """The node of a writer (or reader), else ``dds:<participant guid>`` for a non-ROS one;
        ``None`` while its participant has not yet said which nodes it holds (for at most
        ``grace`` seconds after it appeared)."""
        node = self.node_of_endpoint.get(writer_guid)
        if node is not None:
            return node
        e = self.endpoints.get(writer_guid)
        p = self.participants.get(e.participant) if e is not None else None
        if p is not None and not p.nodes and now - p.first_seen < grace:
            return None
        return f"dds:{e.participant if e else writer_guid}"

    def _endpoint_node(self, e: Endpoint) -> str:
        return self.node_of_endpoint.get(e.guid) or f"dds:{e.participant}"

    def node_alive(self, name: str) -> bool:
        p = self.participants.get(self.known_nodes.get(name, ""))
        return p is not None and p.alive and name in p.nodes

    def snapshot(self, now: float) -> GraphSnapshot:
        nodes: dict[str, NodeInfo] = {}
        for name, guid in sorted(self.known_nodes.items()):
            p = self.participants.get(guid)
            alive = self.node_alive(name)
            nodes[name] = NodeInfo(name, alive, p.pid if p else None, p.host if p else None)
        pubs: dict[str, set[str]] = {}
        subs: dict[str, set[str]] = {}
        types: dict[str, str] = {}
        for e in self.endpoints.values():
            topic = e.topic
            if topic is None:
                continue
            types.setdefault(topic, e.type)
            (pubs if e.writer else subs).setdefault(topic, set()).add(self._endpoint_node(e))
        topics = {t: TopicInfo(t, types[t], tuple(sorted(pubs.get(t, ()))),
                               tuple(sorted(subs.get(t, ()))))
                  for t in sorted(types)}
        return GraphSnapshot(now, nodes, topics)

    def writers_of(self, topic: str) -> list[Endpoint]:
        return [e for e in self.endpoints.values() if e.writer and e.topic == topic]

    def describe(self, e: Endpoint) -> str:
        role = "publisher" if e.writer else "subscriber"
        return f"{role} {self._endpoint_node(e)} on {e.topic} ({e.type}): {e.qos.describe()}"

    def incompatible_pairs(self) -> list[tuple[Endpoint, Endpoint, list[str]]]:
        """Every (writer, reader, reasons) on one ROS topic whose QoS do not match."""
        out = []
        writers: dict[str, list[Endpoint]] = {}
        for e in self.endpoints.values():
            if e.writer and e.topic is not None:
                writers.setdefault(e.topic, []).append(e)
        for r in self.endpoints.values():
            if r.writer or r.topic is None:
                continue
            for w in writers.get(r.topic, ()):
                why = incompatibilities(w.qos, r.qos)
                if why:
                    out.append((w, r, why))
        return out

    def node_name_of_pair(self, w: Endpoint, r: Endpoint) -> tuple[str, str]:
        return self._endpoint_node(w), self._endpoint_node(r)
