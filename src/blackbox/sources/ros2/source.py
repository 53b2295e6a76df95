"""``Ros2Source``: a live ROS 2 robot watched over DDS, without rclpy and without a node.

One background thread does all DDS work: it reads the builtin discovery topics and
``ros_discovery_info`` a few times a second (the graph round: nodes, topics, QoS, process
liveness, resources) and, in between, waits on the topic readers and takes their samples
as raw CDR. Everything goes into one bounded queue; ``poll(until)`` sleeps until the wall
clock reaches ``until`` and hands out what arrived. Source time is wall-clock seconds.

A publisher whose DDS participant is new (a node started or restarted) cannot be named
until that participant lists its nodes on ``ros_discovery_info``; its messages meanwhile are
held back (never reported under a wrong name), so its topic is a
:class:`~blackbox.events.MeasurementGap` from its first held-back message until the
participant has named its nodes (at most ``node_info_grace`` s): a restarted node's rate is
not judged on the messages the black box could not attribute. The black box itself paused
or its clock stepped is a gap of everything
(:class:`~blackbox.sources.clockwatch.ClockWatch`).

Topic readers are created only for topics the observers ask for, once a publisher of the
topic is known, with the reader type generated from the ``rosbags`` type store
(:mod:`blackbox.sources.ros2.idl`) and a QoS every publisher of the topic can serve:
reliable only if all of them are reliable, always volatile, never a deadline or a
liveliness request. Messages decode lazily with ``rosbags`` from the raw CDR.

A topic is unmeasured (a :class:`~blackbox.events.MeasurementGap`) from the start until its
first message arrives, at most ``first_message_limit`` s: discovery, matching and the node
names take seconds, and the messages held back meanwhile are not the robot's silence (as
the ROS 1 source's gap while it connects).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import socket
import threading
import time
import uuid
from collections import deque
from functools import partial
from pathlib import Path
from typing import Any

import psutil
from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsParticipant,
    BuiltinTopicDcpsPublication,
    BuiltinTopicDcpsSubscription,
)
from cyclonedds.core import (
    DDSException,
    GuardCondition,
    InstanceState,
    ReadCondition,
    SampleState,
    ViewState,
)
from cyclonedds.core import WaitSet as _WaitSet
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as idl_types
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from rosbags.typesys.store import Typestore

from blackbox.config.node import ConfigError
from blackbox.events import (
    ArrivalBatch,
    Event,
    GraphSnapshot,
    Interest,
    MeasurementGap,
    MessageArrival,
    TopicSchema,
)
from blackbox.model import BlackBoxEvent
from blackbox.sources.base import SOURCES, Capabilities, SourceKind, SourceOptions
from blackbox.sources.clockwatch import ClockWatch
from blackbox.sources.handout import overflow_event, split_due, wait_until
from blackbox.sources.ros1.resources import ResourceSampler
from blackbox.sources.ros2.graph import Endpoint, Ros2Graph
from blackbox.sources.ros2.idl import IdlTypes, UnknownRos2Type, ros_type_name
from blackbox.sources.ros2.qos import EndpointQos
from blackbox.sources.ros2.writer_time import WriterDelay
from blackbox.sources.starvation import StarvationGaps
from blackbox.transport.participant import LOOPBACK_CONFIG

__all__ = ["ROS2_CAPABILITIES", "Ros2Settings", "Ros2Source", "cyclone_config_for_ros2",
           "domain_id_from_spec"]

log = logging.getLogger("blackbox.sources.ros2")

IGNORE_TYPE_INFORMATION = ("<Compatibility><IgnoreTypeInformation>1.15"
                           "</IgnoreTypeInformation></Compatibility>")
"""Without it Cyclone never matches Fast DDS's ``ros_discovery_info`` writers."""

_ANY = SampleState.Any | ViewState.Any | InstanceState.Any
_TAKE_BATCH = 256
_NS = 1_000_000_000
TAKE_LIMIT = 1.0
"""Seconds ``poll`` waits for the DDS thread to take what arrived before its horizon; past
that the black box is starved of CPU and the stretch is a measurement gap of everything."""

ROS2_CAPABILITIES = Capabilities(snapshot_format="mcap", diagnostics_bridge="ros2")


def domain_id_from_spec(spec: str, environ: dict[str, str] | os._Environ[str] = os.environ
                        ) -> int:
    """``ros2`` -> ``$ROS_DOMAIN_ID`` (default 0); ``ros2:N`` -> N."""
    if spec == "ros2":
        text, where = environ.get("ROS_DOMAIN_ID", "") or "0", "ROS_DOMAIN_ID"
    elif spec.startswith("ros2:"):
        text, where = spec.removeprefix("ros2:"), "--source"
    else:
        raise ConfigError(f"not a ROS 2 source: {spec!r}", "--source")
    try:
        domain = int(text)
    except ValueError:
        domain = -1
    if not 0 <= domain <= 232:
        raise ConfigError(f"bad ROS 2 domain id {text!r} ({where}); expected ros2 or "
                          "ros2:DOMAIN_ID with a domain id 0..232", "--source")
    return domain


def cyclone_config_for_ros2(explicit: str | None = None,
                            environ: dict[str, str] | os._Environ[str] = os.environ) -> str:
    """The Cyclone configuration: ``explicit``, else ``$CYCLONEDDS_URI``, else loopback;
    always with the compatibility setting Fast DDS interop needs."""
    base = explicit or environ.get("CYCLONEDDS_URI") or LOOPBACK_CONFIG
    return f"{base},{IGNORE_TYPE_INFORMATION}" if "," in base or "://" in base else \
        base + IGNORE_TYPE_INFORMATION


@dataclasses.dataclass(frozen=True, slots=True)
class Ros2Settings:
    """How a ROS 2 robot is watched: seconds between graph rounds and resource samples,
    how long to wait for a first ROS 2 participant before saying so, how long messages of a
    new participant are held back until it says which nodes it holds (ROS 2 announces
    that on ``ros_discovery_info``, which reaches a late joiner only after the writer's
    next heartbeat, about 3 s with Fast DDS; messages meanwhile are not reported, so that
    no publisher is ever reported under a wrong name; the first graph snapshot waits for
    that too, and for ``discovery_settle`` seconds of discovery), the event queue's
    bound, each topic reader's history depth, the Cyclone configuration (``None``: see
    :func:`cyclone_config_for_ros2`) and the type store (``None``: ROS 2 Kilted's)."""

    graph_period: float = 0.2
    resource_period: float = 1.0
    no_participant_grace: float = 3.0
    node_info_grace: float = 5.0
    discovery_settle: float = 1.0
    first_message_limit: float = 10.0
    """Seconds a topic stays unmeasured after the start at most, waiting for its first
    message: past that, its silence is the robot's (a publisher dead at start times out)."""
    queue_limit: int = 200_000
    reader_depth: int = 100
    cyclone_config: str | None = None
    typestore: Typestore | None = None


@dataclasses.dataclass(slots=True)
class _TopicReader:
    topic: str
    ros_type: str
    reader: DataReader[Any]
    decodable: bool
    reliable: bool


@dataclasses.dataclass(slots=True)
class _Process:
    proc: psutil.Process
    running: bool = True


def _machine_id() -> str:
    for path in ("/etc/machine-id", "/var/lib/dbus/machine-id"):
        try:
            return Path(path).read_text().strip()
        except OSError:
            continue
    return ""


def _properties(qos: Qos | None) -> dict[str, str]:
    props: dict[str, str] = {}
    if qos is None:
        return props
    for policy in qos:
        key = getattr(policy, "key", None)
        if key is not None:
            props[str(key)] = str(getattr(policy, "value", ""))
    return props


def _key_of(sample: Any) -> str:
    key = getattr(sample, "key", None)
    if key is None:  # an InvalidSample (dispose without data) holds the key sample
        key = getattr(getattr(sample, "sample", None), "key", None)
    return str(key)


def _alive(sample: Any) -> bool:
    info = getattr(sample, "sample_info", None)
    return info is None or info.instance_state == InstanceState.Alive


class Ros2Source:
    """A live ROS 2 domain, observed with Cyclone DDS and invisible to the ROS graph."""

    def __init__(self, domain_id: int, settings: Ros2Settings | None = None) -> None:
        self.settings = settings = settings or Ros2Settings()
        self.domain_id = domain_id
        self.name = f"ros2 domain {domain_id}"
        self.capabilities = ROS2_CAPABILITIES
        self.graph = Ros2Graph()
        self._types = IdlTypes(settings.typestore)
        self._queue: deque[Event] = deque()
        self._lock = threading.Lock()
        self._dropped = 0
        self._held: list[Event] = []
        self._stop = threading.Event()
        self._clock = ClockWatch()
        self._thread: threading.Thread | None = None
        self._interest = Interest()
        self._waiting: dict[str, MeasurementGap] = {}
        """Topic -> its open start gap, closed by its first message (under ``_lock``)."""
        self._readers: dict[str, _TopicReader] = {}
        self._writer_of_handle: dict[int, str] = {}
        self._writer_delay = WriterDelay()
        """Arrival times from the writers' source timestamps (``writer_time``)."""
        self._procs: dict[str, _Process] = {}
        self.starvation = StarvationGaps()
        """CPU starvation of the black box and of the robot's local publishers, from their
        threads' run-queue waits; tests give its ``watch`` ``schedstat`` files of their own."""
        self._resources = ResourceSampler()
        self._reported: set[tuple[str, ...]] = set()
        self._alive_nodes: dict[str, bool] = {}
        self._unattributed = 0
        self._participant_of_handle: dict[int, tuple[str, float]] = {}
        """Publication handle -> (its participant's guid, when this source first met it)."""
        self._unnamed_gaps: dict[tuple[str, str], MeasurementGap] = {}
        """(topic, participant guid) -> the open gap of a topic whose messages from a new
        participant are held back until it names its nodes."""
        self._graph_ready = False
        self._handed_out = 0.0
        self._taken = threading.Condition()
        self._taken_through = 0.0
        """Wall time at which the DDS thread's latest pass over the readers began: every
        sample received before it has been taken (under ``_taken``)."""
        self._nudge: GuardCondition | None = None
        self._machine_id = _machine_id()
        self._hostname = socket.gethostname()
        self._domain: Domain | None = None
        self._participant: DomainParticipant | None = None
        self._ready = threading.Event()
        self._start_error: BaseException | None = None
        self._configure_domain()

    def _configure_domain(self) -> None:
        """Configure Cyclone's domain now, when the source is opened: a DDS sink of the
        same process opened later (UCMS transport, ``/diagnostics``) then shares this
        configuration, which Fast DDS interop needs."""
        config = cyclone_config_for_ros2(self.settings.cyclone_config)
        try:
            self._domain = Domain(self.domain_id, config)
        except DDSException:  # this process already runs the domain
            log.warning("DDS domain %d was opened earlier in this process; its configuration "
                        "may lack the Fast DDS compatibility setting (%s)", self.domain_id,
                        IGNORE_TYPE_INFORMATION)

    @classmethod
    def from_spec(cls, spec: str, settings: Ros2Settings | None = None) -> Ros2Source:
        return cls(domain_id_from_spec(spec), settings)

    # ---- Source protocol -------------------------------------------------------------------

    def start(self, interest: Interest) -> None:
        if self._thread is not None:
            raise RuntimeError("Ros2Source started twice")
        self._interest = interest
        now = time.time()
        for topic in sorted(interest.topics):
            self._waiting[topic] = gap = MeasurementGap(
                now, now, None, f"waiting for the first message of {topic} since the start "
                "(DDS discovery and node names)", topic=topic)
            self._queue.append(gap)
        self._thread = threading.Thread(target=self._run, name="ros2-dds", daemon=True)
        self._thread.start()
        self._ready.wait(10.0)
        if self._start_error is not None:
            raise self._start_error

    def now(self) -> float:
        return time.time()

    def poll(self, until: float) -> list[Event]:
        wait_until(self._stop, until)
        pause = self._clock.check(expected=until)
        if pause is None and not self._await_taken(until):
            pause = MeasurementGap(time.time(), self._handed_out or until, time.time(),
                                   f"the black box's DDS thread did not take its samples "
                                   f"within {TAKE_LIMIT:g} s (starved of CPU)")
        # Starvation (docs/ros2.md): the black box's own threads waited for a CPU (a gap of
        # everything), or a local publisher did (a gap of its topics: the host's load).
        starved = self.starvation.check(self._handed_out, until, time.time())
        if pause is None:
            pause = starved.own
        for message in starved.saturated:
            self._report("host_saturated", self._hostname, message)
        events = self._held
        self._held = []
        events.extend(starved.gaps)
        with self._lock:
            self._handed_out = max(self._handed_out, until)
            events.extend(self._queue)
            self._queue.clear()
            dropped, self._dropped = self._dropped, 0
        if dropped:
            events.append(overflow_event(time.time(), "ros2_queue_overflow", dropped,
                                         self.name))
        due, self._held = split_due(events, until)
        if pause is not None:  # the black box paused or its clock stepped: a gap
            due.insert(0, pause)
        return due

    def _await_taken(self, until: float) -> bool:
        """Wake the DDS thread and wait (at most :data:`TAKE_LIMIT` s) until it has taken
        every sample received before ``until``; ``False`` if it did not in time.

        Samples are stamped when the DDS thread takes them. Handed out before it had run
        (a busy machine: this thread woke, that one not yet), what the robot sent just
        before ``until`` was missing at the evaluation (silence: a time-out, a long period)
        and came after it crowded at the horizon (a burst): false alarms that were the
        black box's own lag."""
        nudge = self._nudge
        if nudge is None or not self._readers:
            return True
        nudge.set(True)
        with self._taken:
            return self._taken.wait_for(
                lambda: self._taken_through >= until or self._stop.is_set(), TAKE_LIMIT)

    def schema(self, topic: str) -> TopicSchema | None:
        return None

    def close(self) -> None:
        self._stop.set()
        with self._taken:
            self._taken.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=3.0)

    # ---- queue -----------------------------------------------------------------------------

    def _push(self, event: Event) -> None:
        with self._lock:
            if event.time < self._handed_out and not isinstance(event, (MessageArrival,
                                                                       ArrivalBatch)):
                event = dataclasses.replace(event, time=self._handed_out)  # keep time order
            if len(self._queue) < self.settings.queue_limit:
                self._queue.append(event)
            else:
                self._dropped += 1

    def _expire_waiting(self, now: float) -> None:
        """Close the start gaps of topics silent for ``first_message_limit`` s: from then
        on their silence is judged."""
        limit = self.settings.first_message_limit
        with self._lock:
            for topic, gap in list(self._waiting.items()):
                if now - gap.start >= limit:
                    del self._waiting[topic]
                    self._queue.append(MeasurementGap(
                        max(now, self._handed_out), gap.start, now,
                        f"{gap.reason}; no message within {limit:g} s, judging its silence",
                        topic=topic))

    def _report(self, kind: str, component: str, message: str, *key: str,
                level: int = logging.WARNING) -> None:
        """Report a robot-side finding once per ``key`` (every time if no key)."""
        if key:
            if key in self._reported:
                return
            self._reported.add(key)
        log.log(level, "%s: %s", component, message)
        self._push(BlackBoxEvent(time.time(), f"ros2_{kind}", message, component))

    # ---- the DDS thread --------------------------------------------------------------------

    def _open(self) -> None:
        dp = self._participant = DomainParticipant(self.domain_id)
        self.graph.own_participants.add(str(dp.guid))
        self._dcps_participants = BuiltinDataReader(dp, BuiltinTopicDcpsParticipant)
        self._dcps_writers = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
        self._dcps_readers = BuiltinDataReader(dp, BuiltinTopicDcpsSubscription)
        info_type = self._types.struct("rmw_dds_common/msg/ParticipantEntitiesInfo")
        self._discovery = DataReader(
            dp, Topic(dp, "ros_discovery_info", info_type),
            Qos(Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal,
                Policy.History.KeepAll))
        self._waitset = _WaitSet(dp)
        self._nudge = GuardCondition(dp)
        self._waitset.attach(self._nudge)

    def _run(self) -> None:
        try:
            self._open()
        except BaseException as exc:
            self._start_error = exc
            self._ready.set()
            return
        self._ready.set()
        started = time.time()
        next_graph = started
        next_resources = started
        period = self.settings.graph_period
        try:
            while not self._stop.is_set():
                now = time.time()
                if now >= next_graph:
                    next_graph = now + period
                    try:
                        self._graph_round(now, started)
                        if now >= next_resources:
                            next_resources = now + self.settings.resource_period
                            self._sample_resources(now)
                    except Exception as exc:  # the DDS thread must outlive any surprise
                        log.exception("graph round failed")
                        self._report("graph_error", self.name, f"graph round failed: {exc!r}")
                self._expire_waiting(now)
                wait = max(0.0, next_graph - time.time())
                if self._readers:
                    self._waitset.wait(int(wait * _NS))
                    assert self._nudge is not None
                    self._nudge.set(False)
                    began = time.time()
                    self._take_all()
                    with self._taken:
                        self._taken_through = began
                        self._taken.notify_all()
                else:
                    self._stop.wait(wait)
        finally:
            self._shutdown()

    def _shutdown(self) -> None:
        dp = self._participant
        self._readers.clear()
        if dp is not None:
            self._participant = None
            dp.__del__()
        self._domain = None

    # ---- topics ----------------------------------------------------------------------------

    def _take_all(self) -> None:
        for tr in list(self._readers.values()):
            while True:
                try:
                    batch = _raw_take(tr.reader)
                except DDSException as exc:
                    self._report("read_error", tr.topic, f"reading {tr.topic} failed: {exc}")
                    break
                if batch:
                    self._deliver(tr, batch)
                if len(batch) < _TAKE_BATCH:
                    break

    def _deliver(self, tr: _TopicReader, batch: list[tuple[bytes, Any]]) -> None:
        store = self._types.store
        stamp = time.time()
        decoded = tr.decodable and tr.topic in self._interest.decoded
        arrivals: list[MessageArrival] = []
        writer_delay = self._writer_delay
        for data, info in batch:
            if not info.valid_data:
                continue
            publisher = self._publisher_of(tr.reader, info.publication_handle, stamp)
            if publisher is None:
                self._unattributed += 1
                self._held_back(tr.topic, info.publication_handle, stamp)
                continue
            raw = bytes(data)
            decode = partial(_decode, store, raw, tr.ros_type) if decoded else None
            sent = info.source_timestamp
            arrived = max(stamp if sent <= 0 else writer_delay.arrival(
                info.publication_handle, sent / _NS, stamp), self._handed_out)
            arrivals.append(MessageArrival(arrived, tr.topic, publisher, max(0, len(raw) - 4),
                                           decode=decode, raw=partial(_identity, raw)))
        with self._lock:
            for a in arrivals:  # never before what poll already handed out
                a.time = max(a.time, self._handed_out)
            gap = self._waiting.pop(tr.topic, None) if arrivals else None
            if gap is not None:  # measured from its first message on
                first = min(a.time for a in arrivals)
                self._queue.append(MeasurementGap(first, gap.start, first, gap.reason,
                                                  topic=tr.topic))
            room = self.settings.queue_limit - len(self._queue)
            self._queue.extend(arrivals[:max(0, room)])
            self._dropped += max(0, len(arrivals) - max(0, room))

    def _publisher_of(self, reader: DataReader[Any], handle: int, now: float) -> str | None:
        """The node of the writer behind ``handle``; ``None`` (held back) while it cannot be
        named yet: its participant has not listed its nodes, or discovery has not yet told
        this source of the writer or its participant (data can overtake the builtin
        topics), for at most ``node_info_grace`` s."""
        guid = self._writer_of_handle.get(handle)
        grace = self.settings.node_info_grace
        if guid is None:
            try:
                match = reader.get_matched_publication_data(handle)
            except DDSException:
                match = None
            if match is None:  # the writer left between the sample and this lookup
                return "dds:unknown"
            guid = str(match.key)
            self._writer_of_handle[handle] = guid
            self._participant_of_handle[handle] = (str(match.participant_key), now)
        name = self.graph.publisher_name(guid, now, grace)
        if name is not None and name.startswith("dds:"):
            participant, first = self._participant_of_handle.get(handle, ("", -grace))
            if now - first < grace and (guid not in self.graph.endpoints
                                        or participant not in self.graph.participants):
                return None
        return name

    def _held_back(self, topic: str, handle: int, now: float) -> None:
        """A message of ``topic`` from a participant that has not yet named its nodes was
        held back: the topic is not measured until it has (:meth:`_close_unnamed_gaps`)."""
        participant = self._participant_of_handle.get(handle, ("", 0.0))[0]
        key = (topic, participant)
        if key in self._unnamed_gaps:
            return
        p = self.graph.participants.get(participant)
        pid = f" (pid {p.pid})" if p is not None and p.pid is not None else ""
        gap = MeasurementGap(now, now, None, f"a new DDS participant{pid} publishes {topic}; "
                             "its messages are held back until it names its nodes "
                             "(ros_discovery_info)", topic=topic)
        self._unnamed_gaps[key] = gap
        self._push(gap)

    def _close_unnamed_gaps(self, now: float) -> None:
        """Close the held-back gaps whose participant named its nodes, left, or stayed
        unnamed past ``node_info_grace`` (its messages are then reported as ``dds:...``)."""
        grace = self.settings.node_info_grace
        for key, gap in list(self._unnamed_gaps.items()):
            p = self.graph.participants.get(key[1])
            if p is None and now - gap.start < grace:
                continue  # not yet discovered
            if p is not None and p.alive and not p.nodes and now - p.first_seen < grace:
                continue
            del self._unnamed_gaps[key]
            why = (f"named: {', '.join(p.nodes)}" if p is not None and p.nodes
                   else "it left" if p is None or not p.alive
                   else f"unnamed after {grace:g} s, reported as a DDS participant")
            self._push(MeasurementGap(now, gap.start, now, f"{gap.reason}; {why}", gap.topic))

    def _ensure_readers(self) -> None:
        assert self._participant is not None
        for topic in sorted(self._interest.topics):
            writers = self.graph.writers_of(topic)
            if not writers:
                continue
            reliable = all(w.qos.reliability == "reliable" for w in writers)
            tr = self._readers.get(topic)
            if tr is not None:
                if tr.reliable and not reliable:  # a best-effort publisher joined
                    self._drop_reader(tr)
                else:
                    self._check_types(tr, writers)
                    continue
            self._readers[topic] = self._make_reader(topic, writers[0], reliable)
            self._check_types(self._readers[topic], writers)

    def _make_reader(self, topic: str, writer: Endpoint, reliable: bool) -> _TopicReader:
        assert self._participant is not None
        ros_type = ros_type_name(writer.dds_type) or writer.dds_type
        decodable = True
        try:
            struct: type[IdlStruct] = self._types.struct(ros_type)
        except UnknownRos2Type as exc:
            decodable = False
            struct = _opaque(writer.dds_type)
            self._report("unknown_type", topic,
                         f"type {ros_type} of {topic} is not in the type store ({exc}); its "
                         "messages are counted (rate, size, publisher) but not decoded",
                         "unknown_type", topic, ros_type)
        qos = Qos(Policy.Reliability.Reliable(0) if reliable else Policy.Reliability.BestEffort,
                  Policy.Durability.Volatile, Policy.History.KeepLast(self.settings.reader_depth))
        reader: DataReader[Any] = DataReader(
            self._participant, Topic(self._participant, writer.dds_topic, struct), qos)
        self._waitset.attach(ReadCondition(reader, _ANY))
        log.info("reading %s (%s, %s)", topic, ros_type,
                 "reliable" if reliable else "best effort")
        return _TopicReader(topic, ros_type, reader, decodable, reliable)

    def _drop_reader(self, tr: _TopicReader) -> None:
        del self._readers[tr.topic]
        tr.reader.__del__()

    def _check_types(self, tr: _TopicReader, writers: list[Endpoint]) -> None:
        for w in writers:
            if w.type != tr.ros_type:
                self._report("type_mismatch", tr.topic,
                             f"{self.graph.publisher_name(w.guid)} publishes {w.type} on "
                             f"{tr.topic}, which is read as {tr.ros_type}; its messages are "
                             "not received", "type_mismatch", w.guid)

    # ---- graph -----------------------------------------------------------------------------

    def _graph_round(self, now: float, started: float) -> None:
        graph = self.graph
        for s in self._dcps_participants.take(_TAKE_BATCH * 4):
            guid = _key_of(s)
            if not _alive(s):
                self._procs.pop(guid, None)
                graph.participant_gone(guid, "its participant left the DDS domain")
                continue
            qos = getattr(s, "qos", None)
            props = _properties(qos)
            userdata = qos[Policy.Userdata] if qos is not None else None
            props["__user_data"] = bytes(getattr(userdata, "data", b"") or b"").decode(
                "utf-8", "replace")
            self._participant_seen(guid, props, now)
        for reader, writer in ((self._dcps_writers, True), (self._dcps_readers, False)):
            for s in reader.take(_TAKE_BATCH * 4):
                if not _alive(s):
                    graph.endpoint_gone(_key_of(s))
                    continue
                e = Endpoint(str(s.key), str(s.participant_key), writer, s.topic_name,
                             s.type_name, EndpointQos.from_dds(s.qos, writer))
                graph.endpoint_seen(e)
        info: Any
        for info in self._discovery.take(_TAKE_BATCH):
            if not _alive(info) or not hasattr(info, "gid"):
                continue
            guid = str(uuid.UUID(bytes=bytes(info.gid.data)))
            graph.nodes_listed(guid, [
                (_node_name(n.node_namespace, n.node_name),
                 [str(uuid.UUID(bytes=bytes(g.data))) for g in n.reader_gid_seq],
                 [str(uuid.UUID(bytes=bytes(g.data))) for g in n.writer_gid_seq])
                for n in info.node_entities_info_seq])
        self._check_processes()
        self._note_local_publishers()
        self._close_unnamed_gaps(now)
        self._show_endpoints(now)
        self._ensure_readers()
        grace = self.settings.node_info_grace
        for w, r, why in graph.incompatible_pairs():
            if (graph.publisher_name(w.guid, now, grace) is None
                    or graph.publisher_name(r.guid, now, grace) is None):
                continue  # named once both nodes are known
            pub, sub = graph.node_name_of_pair(w, r)
            self._report("qos_incompatible", w.topic or "",
                         f"publisher {pub} and subscriber {sub} on {w.topic} cannot "
                         f"communicate: {'; '.join(why)} (publisher {w.qos.describe()}; "
                         f"subscriber {r.qos.describe()})", "qos", w.guid, r.guid)
        if not graph.ros_participants() and now - started >= self.settings.no_participant_grace:
            self._report("no_participants", self.name,
                         f"no ROS 2 participant found on DDS domain {self.domain_id} after "
                         f"{now - started:.0f} s: is the robot running, on this domain "
                         "(ROS_DOMAIN_ID), and does its discovery reach this machine "
                         "(ROS_AUTOMATIC_DISCOVERY_RANGE, loopback)?", "no_participants")
        if not self._graph_ready:
            # The first snapshot waits until discovery settled and every ROS 2 participant
            # named its nodes (bounded): until then observers say "no graph yet" instead
            # of "node not running".
            settled = now - started >= self.settings.discovery_settle
            self._graph_ready = (settled and not graph.unnamed()) or (
                now - started >= self.settings.node_info_grace)
            if not self._graph_ready:
                return
        snapshot = graph.snapshot(now)
        self._node_transitions(snapshot)
        self._push(snapshot)

    def _show_endpoints(self, now: float) -> None:
        """Report each observed topic's endpoints with their QoS, once their node is known."""
        grace = self.settings.node_info_grace
        for e in list(self.graph.endpoints.values()):
            if e.topic not in self._interest.topics or ("endpoint", e.guid) in self._reported:
                continue
            if self.graph.publisher_name(e.guid, now, grace) is not None:
                self._report("endpoint", e.topic or "", self.graph.describe(e), "endpoint",
                             e.guid, level=logging.INFO)

    def _participant_seen(self, guid: str, props: dict[str, str], now: float) -> None:
        pid_text = props.get("fastdds.physical_data.process") or props.get("__Pid")
        pid = int(pid_text) if pid_text and pid_text.isdigit() else None
        host_id = props.get("fastdds.physical_data.host")
        hostname = props.get("__Hostname")
        local = (bool(host_id) and host_id == self._machine_id) or hostname == self._hostname
        host = self._hostname if local else (hostname or host_id)
        p = self.graph.participant_seen(guid, pid, host, local, now,
                                        ros="enclave=" in props.get("__user_data", ""))
        if p is None or not local or pid is None or guid in self._procs:
            return
        try:
            proc = psutil.Process(pid)
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            return  # another pid namespace: liveness from DDS alone
        self._procs[guid] = _Process(proc)

    def _check_processes(self) -> None:
        """Local participants live and die with their process: a killed process is dead at
        the next round, not when its DDS lease (20 s in Fast DDS) runs out."""
        for guid, tracked in list(self._procs.items()):
            p = self.graph.participants.get(guid)
            if p is None:
                continue
            try:
                running = tracked.proc.is_running() and tracked.proc.status() not in (
                    psutil.STATUS_ZOMBIE, psutil.STATUS_DEAD, psutil.STATUS_STOPPED)
            except psutil.NoSuchProcess:
                running = False
            if not tracked.proc.is_running():
                del self._procs[guid]
                self.graph.participant_gone(guid, f"its process {p.pid} exited")
                continue
            if running != tracked.running:
                tracked.running = running
                p.alive = running
                p.why_dead = "" if running else f"its process {p.pid} is stopped"

    def _note_local_publishers(self) -> None:
        """Record the live publishers of watched topics whose process runs on this host,
        with their pids (their run-queue waits tell ``poll`` when the host starved them)."""
        graph = self.graph
        pids: dict[str, int] = {}
        topics: dict[str, tuple[str, ...]] = {}
        for topic in sorted(self._interest.topics | self._interest.decoded):
            for w in graph.writers_of(topic):
                p = graph.participants.get(w.participant)
                node = graph.node_of_endpoint.get(w.guid)
                if p is None or not p.alive or not p.local or p.pid is None or node is None:
                    continue
                pids[node] = p.pid
                if topic not in topics.get(node, ()):
                    topics[node] = (*topics.get(node, ()), topic)
        self.starvation.local_publishers = (pids, topics)

    def _node_transitions(self, snapshot: GraphSnapshot) -> None:
        for name, info in snapshot.nodes.items():
            before = self._alive_nodes.get(name)
            self._alive_nodes[name] = info.alive
            if before is None or before == info.alive:
                continue
            if info.alive:
                self._report("node_alive", name, f"node {name} is back")
            else:
                p = self.graph.participants.get(self.graph.known_nodes.get(name, ""))
                why = p.why_dead if p is not None and p.why_dead else "it left the ROS graph"
                self._report("node_dead", name, f"node {name} is dead: {why}")

    def _sample_resources(self, now: float) -> None:
        if not self._interest.resources:
            return
        nodes = dict(self.graph.snapshot(now).nodes)
        for sample in self._resources.sample(now, self._interest.resources, nodes):
            self._push(sample)


def _raw_take(reader: DataReader[Any]) -> list[tuple[bytes, Any]]:
    """Up to a batch of samples as (serialized CDR, sample info), not deserialized."""
    from cyclonedds._clayer import ddspy_take

    ret = ddspy_take(reader._ref, _ANY, _TAKE_BATCH)
    if isinstance(ret, int):
        raise DDSException(ret, f"taking from {reader!r}")
    return list(ret)


def _decode(store: Typestore, raw: bytes, ros_type: str) -> Any:
    try:
        return store.deserialize_cdr(raw, ros_type)
    except Exception as exc:  # a message that does not fit its type: no value
        log.debug("cannot decode %s: %s", ros_type, exc)
        return None


def _identity(raw: bytes) -> bytes:
    return raw


_OPAQUE: dict[str, type[IdlStruct]] = {}


def _opaque(dds_type: str) -> type[IdlStruct]:
    """A reader type for a message the type store does not know: one octet, so Cyclone
    accepts any sample of the type and the source still sees every arrival."""
    made = _OPAQUE.get(dds_type)
    if made is None:
        name = "opaque_" + "".join(c if c.isalnum() else "_" for c in dds_type)
        made = _OPAQUE[dds_type] = make_idl_struct(name, dds_type,
                                                   {"first_octet": idl_types.uint8})
    return made


def _node_name(namespace: str, name: str) -> str:
    return f"{namespace.rstrip('/')}/{name}"


def open_ros2_source(spec: str, options: SourceOptions) -> Ros2Source:
    return Ros2Source.from_spec(spec)


SOURCES.add("ros2", SourceKind("ros2", open_ros2_source, ROS2_CAPABILITIES,
                               "ros2 or ros2:DOMAIN_ID"))
