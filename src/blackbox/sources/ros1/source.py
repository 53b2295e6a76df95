"""``Ros1Source``: a live ROS 1 robot as a stream of black-box source events.

Two background threads do all I/O: the graph thread (master + node liveness + resources,
a few times a second) and the TCPROS reader (every topic connection). Both append to one
bounded in-memory queue; ``poll(until)`` sleeps until the wall clock reaches ``until`` and
hands out what arrived. Source time is wall-clock seconds (``time.time()``).

What the black box could not measure as it normally does is said with a
:class:`~blackbox.events.MeasurementGap`: a topic's rate switching between the publishers'
counters and a subscription (until the new path delivers, at most ``gap_limit`` s), the
black box's connection to a live publisher closing, and a publisher re-registering under a
new URI (until the new connection delivers, at most ``reconnect_limit`` s), the master
unreachable (the graph is not followed), and the black box itself paused or its wall clock
stepped (:class:`~blackbox.sources.clockwatch.ClockWatch`). A gap whose publisher stops
answering closes at once: from then on its silence is the robot's.

Robot-side faults (master gone, node dead, garbage on a connection, ...) are logged with a
reason and returned from ``poll`` as :class:`~blackbox.model.BlackBoxEvent` s; none of them
stops the source.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from functools import partial
from urllib.parse import parse_qs, urlsplit

import psutil

from blackbox.config.node import ConfigError
from blackbox.events import (
    ArrivalBatch,
    Event,
    Interest,
    MeasurementGap,
    MessageArrival,
    NetworkSample,
    ResourceSample,
    TopicSchema,
)
from blackbox.model import BlackBoxEvent
from blackbox.sources.base import SOURCES, Capabilities, SourceKind, SourceOptions
from blackbox.sources.clockwatch import ClockWatch
from blackbox.sources.handout import overflow_event, split_due, wait_until
from blackbox.sources.ros1.busstats import BusStatsRates, TopicCounts
from blackbox.sources.ros1.callerid import DEFAULT_PREFIX, unique_caller_id, valid_caller_id
from blackbox.sources.ros1.graph import GraphPoller
from blackbox.sources.ros1.master import host_of
from blackbox.sources.ros1.readers import ReaderProcesses
from blackbox.sources.ros1.resources import ResourceSampler, is_local_host
from blackbox.sources.ros1.stream_reader import Arrivals, StreamKey
from blackbox.sources.ros1.subscriber import DEFAULT_MAX_MESSAGE_BYTES, TcprosSubscriber
from blackbox.sources.starvation import StarvationGaps

log = logging.getLogger("blackbox.sources.ros1")

MAX_READERS = 64
BACKLOG_EPSILON = 1e-6
"""Seconds past the last arrival of a gap's first read at which the gap ends."""


def master_uri_from_spec(spec: str, environ: dict[str, str] | os._Environ[str] = os.environ
                         ) -> str:
    """``ros1`` -> ``$ROS_MASTER_URI``; ``ros1://HOST:PORT`` -> ``http://HOST:PORT/``."""
    if spec == "ros1":
        uri = environ.get("ROS_MASTER_URI", "")
        if not uri:
            raise ConfigError("--source ros1 needs ROS_MASTER_URI (for example "
                              "http://robot:11311) or use --source ros1://HOST:PORT", "--source")
        parts = urlsplit(uri)
        if parts.scheme != "http" or not parts.hostname:
            raise ConfigError(f"ROS_MASTER_URI {uri!r} is not an http://HOST:PORT URI",
                              "--source")
        return uri
    if not spec.startswith("ros1://"):
        raise ConfigError(f"not a ROS 1 source: {spec!r}", "--source")
    parts = urlsplit("http://" + spec.removeprefix("ros1://"))
    try:
        port = parts.port
    except ValueError:
        port = None
    if not parts.hostname or port is None or parts.path not in ("", "/"):
        raise ConfigError(f"bad ROS 1 source {spec!r}; expected ros1://HOST:PORT "
                          "(for example ros1://127.0.0.1:11311)", "--source")
    return f"http://{parts.hostname}:{port}/"


def parse_source_spec(spec: str, settings: Ros1Settings) -> tuple[str, Ros1Settings]:
    """``ros1[://HOST:PORT][?caller_id=/NAME][&counters=0|1][&readers=N][&coalesce=S]``
    -> (the spec without its options, ``settings`` with them). ``caller_id`` fixes the
    black box's name on the publishers' connections; ``counters=0`` measures every rate
    through a subscription (as the thesis's black box did) instead of the publishers'
    counters; ``readers=N`` reads timing-only topics in N child processes (0: a thread of
    the black box); ``coalesce=S`` reads a busy connection at most every S seconds (see
    :class:`Ros1Settings`)."""
    base, sep, query = spec.partition("?")
    if not sep:
        return spec, settings
    params = parse_qs(query, keep_blank_values=True)
    unknown = sorted(set(params) - {"caller_id", "counters", "readers", "coalesce"})
    if unknown:
        raise ConfigError(f"unknown ROS 1 source option {unknown[0]!r} in {spec!r}; "
                          "known: caller_id, counters, readers, coalesce", "--source")
    if "readers" in params:
        values = params["readers"]
        if len(values) != 1 or not values[0].isdigit() or int(values[0]) > MAX_READERS:
            raise ConfigError(f"bad readers in {spec!r}: expected readers=N with N from 0 "
                              f"to {MAX_READERS} (reader processes; 0 = none)", "--source")
        settings = dataclasses.replace(settings, readers=int(values[0]))
    if "coalesce" in params:
        values = params["coalesce"]
        try:
            coalesce = float(values[0]) if len(values) == 1 else -1.0
        except ValueError:
            coalesce = -1.0
        if not 0.0 <= coalesce <= 0.1:
            raise ConfigError(f"bad coalesce in {spec!r}: expected coalesce=SECONDS from 0 "
                              "to 0.1 (for example coalesce=0.001)", "--source")
        settings = dataclasses.replace(settings, coalesce=coalesce)
    if "caller_id" in params:
        values = params["caller_id"]
        if len(values) != 1 or not valid_caller_id(values[0]):
            raise ConfigError(f"bad caller_id in {spec!r}: expected one global ROS name such "
                              "as /blackbox_front", "--source")
        settings = dataclasses.replace(settings, caller_id=values[0])
    if "counters" in params:
        values = params["counters"]
        if len(values) != 1 or values[0] not in ("0", "1"):
            raise ConfigError(f"bad counters in {spec!r}: expected counters=0 or counters=1",
                              "--source")
        settings = dataclasses.replace(settings, rates_from_counters=values[0] == "1")
    return base, settings


ROS1_CAPABILITIES = Capabilities(snapshot_format="ros1", diagnostics_bridge="ros1")


READ_LIMIT = 1.0
"""Seconds ``poll`` waits for the TCPROS reader thread to hand on what arrived before its
horizon; past that the black box is starved and the stretch is a gap of everything."""


@dataclasses.dataclass(frozen=True, slots=True)
class Ros1Settings:
    """How a ROS 1 robot is watched: seconds between graph polls and resource samples,
    the time an XML-RPC probe may take, how long a publisher may stay silent before its
    connection counts as idle, the event queue's bound, reconnection back-off (seconds)
    and the default cap of one message (bytes).

    ``caller_id`` is the name the black box gives publishers when it connects; ``None``
    makes a unique one, ``<caller_id_prefix>_<host>_<pid>_<n>``, so two black boxes on one
    robot never replace each other's connections."""

    graph_period: float = 0.45
    probe_timeout: float = 0.5
    resource_period: float = 1.0
    idle_grace: float = 2.0
    queue_limit: int = 200_000
    backoff_min: float = 0.1
    backoff_max: float = 2.0
    default_max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES
    caller_id: str | None = None
    caller_id_prefix: str = DEFAULT_PREFIX
    rates_from_counters: bool = True
    """Rates of topics a live robot node subscribes to come from the publisher's counters
    (``getBusStats``) instead of a subscription, unless their values are observed. The
    counters also tell, either way, when a subscribed topic arrives slower than the robot
    sends it (``ros1_behind``)."""
    behind_tolerance: float = 0.1
    """Fraction of a subscribed topic's messages the black box may miss (against an
    on-robot subscriber, over ``behind_window`` s) before it says it cannot keep up."""
    behind_window: float = 5.0
    readers: int = 0
    """Child processes reading the timing-only topics (:mod:`blackbox.sources.ros1.readers`);
    0 reads every topic in a thread of the black box. One reader thread takes about
    100k msg/s when publishers write several messages per send but pays a wake-up per
    message for publishers that send each alone (rospy, roscpp); processes spread that
    over the cores (see docs/benchmarks.md, "Scaling over real TCPROS")."""
    coalesce: float = 0.0
    """Seconds a reader waits after a wake-up before reading again (0: read at once). A
    fast topic is then read several messages at a time, saving a wake-up per message;
    messages of one topic closer together than this share one arrival time (the mean
    period stays right, single periods do not; topics slower than ``1 / coalesce`` keep
    exact times)."""
    gap_limit: float = 2.0
    """Seconds a topic switched from the publishers' counters to a subscription stays
    unmeasured at most while waiting for its first message: past that, its silence is the
    robot's again (a publisher that stopped meanwhile then times out)."""
    reconnect_limit: float = 4.0
    """Seconds a topic stays unmeasured at most after the black box's connection to a live
    publisher closed or the publisher re-registered under a new URI, waiting for the first
    message on the new connection: a graph round, the reconnection back-off (at most
    ``backoff_max``) and the handshake."""
    connect_timeout: float = 3.0
    """Seconds a publisher may take to answer ``requestTopic`` and the TCPROS handshake: a
    node that answers its XML-RPC API slowly (seconds) is still subscribed to."""


class Ros1Source:
    """A live ROS 1 robot, observed without registering anything with its master."""

    def __init__(self, master_uri: str, settings: Ros1Settings | None = None) -> None:
        settings = settings or Ros1Settings()
        self.master_uri = master_uri
        self.settings = settings
        self.name = f"ros1 {master_uri}"
        self.capabilities = ROS1_CAPABILITIES
        self._graph_period = settings.graph_period
        self._resource_period = settings.resource_period
        self._idle_grace = settings.idle_grace
        self._queue: deque[Event | BlackBoxEvent] = deque()
        self._lock = threading.Lock()
        self._queue_limit = settings.queue_limit
        self._dropped = 0
        self._floor = 0.0
        self._held: list[Event | BlackBoxEvent] = []
        self._stop = threading.Event()
        self._heard: dict[str, float] = {}
        """Publisher node -> kernel receive time (wall clock, no ``clock_offset``) of its
        latest message: a node whose API is slow but whose messages arrive is running."""
        self._poller = GraphPoller(master_uri, self._report,
                                   probe_timeout=settings.probe_timeout,
                                   heard_from=self._heard.get)
        self._backoff = (settings.backoff_min, settings.backoff_max)
        self._default_cap = settings.default_max_message_bytes
        self._resources = ResourceSampler()
        self._subscriber: TcprosSubscriber | None = None
        self._thread: threading.Thread | None = None
        self._interest = Interest()
        self.caller_id = settings.caller_id or unique_caller_id(settings.caller_id_prefix)
        self._bus = BusStatsRates(caller_id=self.caller_id)
        self.counted: set[tuple[str, str]] = set()
        """(topic, publisher) pairs whose rate currently comes from the publisher's counters."""
        self.behind: set[str] = set()
        """Subscribed topics the black box currently cannot keep up with."""
        self._behind_counts: dict[str, deque[tuple[float, int, int]]] = {}
        self.clock_offset = 0.0
        """Seconds added to every time this source reads or stamps: 0 on a robot; tests
        step it to step the wall clock at the source boundary, kernel stamps included."""
        self._clock = ClockWatch(self._wall)
        self._waiting: dict[tuple[str, str], MeasurementGap] = {}
        """(topic, publisher) switched to a subscription -> its open gap, closed by the
        first message that arrives (or after ``gap_limit``)."""
        self._master_gap: MeasurementGap | None = None
        self._limits: dict[tuple[str, str], float] = {}
        """Open gaps with a limit other than ``gap_limit`` (reconnections)."""
        self._counted_ahead: dict[tuple[str, str], float] = {}
        """Open switch gaps -> the end of the counted arrivals queued before the switch,
        where that is ahead of the switch: the gap ends no earlier (see
        :meth:`_switch_to_subscription`)."""
        self._connected: set[StreamKey] = set()
        self._counted_until: dict[tuple[str, str], float] = {}
        """(topic, publisher) -> the time of the last counted arrival queued: the next
        round's arrivals continue from there (see :meth:`_push_counted`)."""
        self._uris: dict[str, str] = {}
        self._last_round = 0.0
        self._counts_done = threading.Condition()
        self._covered: dict[tuple[str, str], float] = {}
        """Counted (topic, publisher) -> the time (with ``clock_offset``) up to which the
        publisher's counters have been read and queued; ``poll`` waits for it to reach its
        horizon (:meth:`_await_counts`). Under ``_counts_done``."""
        self.starvation = StarvationGaps()
        """CPU starvation of the black box and of the robot's local publishers, from their
        threads' run-queue waits; tests give its ``watch`` ``schedstat`` files of their own."""

    @classmethod
    def from_uri(cls, spec: str, settings: Ros1Settings | None = None) -> Ros1Source:
        """``ros1://HOST:PORT`` or ``ros1``, with the options of :func:`parse_source_spec`."""
        spec, settings = parse_source_spec(spec, settings or Ros1Settings())
        return cls(master_uri_from_spec(spec), settings)

    # ---- Source protocol -------------------------------------------------------------------

    def start(self, interest: Interest) -> None:
        if self._thread is not None:
            raise RuntimeError("Ros1Source started twice")
        self._interest = interest
        self._subscriber = TcprosSubscriber(
            interest.topics, interest.decoded, interest.max_message_bytes, self._push_message,
            self._report, backoff_min=self._backoff[0], backoff_max=self._backoff[1],
            default_max_bytes=self._default_cap, caller_id=self.caller_id,
            on_batch=self._push_batch, readers=self.settings.readers,
            coalesce=self.settings.coalesce, connect_timeout=self.settings.connect_timeout)
        self._subscriber.start()
        self._thread = threading.Thread(target=self._graph_loop, name="ros1-graph",
                                        daemon=True)
        self._thread.start()

    def _wall(self) -> float:
        return time.time() + self.clock_offset

    def now(self) -> float:
        return self._wall()

    def poll(self, until: float) -> list[Event]:
        gap = self._clock.check()  # a clock step since the last poll: do not wait on it
        if gap is None:
            wait_until(self._stop, until - self.clock_offset)
            gap = self._clock.check(expected=until)
        back = gap is not None and gap.end is not None and gap.end < gap.start
        if back:
            assert gap is not None and gap.end is not None
            until = gap.end
        if gap is None:
            self._await_counts(until)
        if self._subscriber is not None:  # the native reader holds arrivals until asked
            # Waited for, not just asked: a reader thread that has not run since ``until``
            # still holds what arrived before it, and handed out without it that stretch
            # was silence, then a burst. Not in time is the black box starved: a gap.
            flushed = self._subscriber.reader.flush(READ_LIMIT)
            if not flushed and gap is None:
                now = self._wall()
                gap = MeasurementGap(now, self._floor or until, now, "the black box's "
                                     f"TCPROS reader did not run for {READ_LIMIT:g} s "
                                     "(starved of CPU)")
        # Starvation (docs/ros1.md): the black box's own threads waited for a CPU (a gap
        # of everything), or a local publisher did (a gap of its topics: the host's load).
        starved = self.starvation.check(self._floor, until, self._wall())
        if gap is None:
            gap = starved.own
        for message in starved.saturated:
            self._report("host_saturated", socket.gethostname(), message)
        queue = self._queue
        events = self._held
        self._held = []
        events.extend(starved.gaps)
        with self._lock:  # every event stamped before this instant is in the queue
            self._floor = until if back else max(self._floor, until)
            while queue:
                events.append(queue.popleft())
        if back:  # measured on the clock before the step: inside the gap
            events = [e for e in events if isinstance(e, BlackBoxEvent) or e.time <= until]
        if self._dropped:
            dropped, self._dropped = self._dropped, 0
            events.append(overflow_event(self._wall(), "ros1_queue_overflow", dropped,
                                         self.name))
        due, self._held = split_due(events, until)
        if gap is not None:
            log.warning("%s", gap.reason)
            due.insert(0, gap)
        return due

    def _await_counts(self, until: float) -> None:
        """Wait until every counted topic has been counted up to ``until`` (a round of the
        graph thread reads the publishers' counters and queues what they sent since the
        previous round), at most a graph period, a probe time-out and half a second.

        A round waits for its slowest reply: when a node stops (a stall, a busy robot)
        the counts of every other publisher come up to a probe time-out later than usual.
        Handed out before they came, the uncounted stretch was silence to the observers
        (a provisional period at an evaluation, then a hole in the arrivals: a wrong rate
        on a healthy topic, the false alarms of the real campaign during stalls). A topic
        still not counted up to ``until`` after the wait is a measurement gap from where its
        counts end until its next counts: the black box could not keep up, which says
        nothing about the robot."""
        settings = self.settings
        deadline = time.monotonic() + settings.graph_period + settings.probe_timeout + 0.5
        late: dict[tuple[str, str], float] = {}
        with self._counts_done:
            while not self._stop.is_set():
                late = {k: t for k, t in self._covered.items()
                        if t < until and k not in self._waiting}
                remaining = deadline - time.monotonic()
                if not late or remaining <= 0:
                    break
                self._counts_done.wait(remaining)
        for key, covered in sorted(late.items()):
            with self._lock:
                self._counted_until.pop(key, None)
            self._open_gap(key, f"the publisher's counters for {key[1]} were not read in "
                           f"time (the black box's rounds are late)",
                           start=covered - self.clock_offset)

    @property
    def reader_processes(self) -> ReaderProcesses | None:
        """The child processes reading timing-only topics (``readers`` > 0), once started."""
        return self._subscriber.processes if self._subscriber else None

    def schema(self, topic: str) -> TopicSchema | None:
        return self._subscriber.schemas.get(topic) if self._subscriber else None

    def close(self) -> None:
        self._stop.set()
        with self._counts_done:
            self._counts_done.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        if self._subscriber is not None:
            self._subscriber.close()
        self._poller.close()

    # ---- background ------------------------------------------------------------------------

    def _push_message(self, msg: MessageArrival) -> None:
        self._push_batch([msg])

    def _push_batch(self, batch: Arrivals) -> None:
        """Queue the arrivals of one read under one lock.

        They carry the kernel's receive time, which may be a little before the last
        ``until`` ``poll`` already handed out; such a stamp is raised to that ``until`` so
        events keep coming in time order. :class:`ArrivalBatch` es go out as they are when
        the interest takes them, else as one arrival per message.
        """
        if not self._interest.arrival_batches:
            batch = [a for item in batch for a in
                     (item.arrivals() if type(item) is ArrivalBatch else (item,))]
        offset = self.clock_offset
        heard = self._heard
        with self._lock:
            floor = self._floor
            room = self._queue_limit - len(self._queue)
            if room < len(batch):
                self._dropped += len(batch) - max(0, room)
                batch = batch[:max(0, room)]
            for msg in batch:
                heard[msg.publisher] = msg.time
                msg.time += offset
                if msg.time < floor:
                    msg.time = floor
            if self._waiting:
                # The first read on a new connection may hold a backlog (the reader started
                # late) under one kernel stamp: it belongs to the gap, which ends just
                # after it, so the backlog never reads as a burst of zero periods.
                first: dict[tuple[str, str], float] = {}
                for msg in batch:
                    key = (msg.topic, msg.publisher)
                    if key in self._waiting:
                        first[key] = max(first.get(key, msg.time), msg.time)
                for key, last in first.items():
                    self._resume(key, last + BACKLOG_EPSILON)
            self._queue.extend(batch)

    def _resume(self, key: tuple[str, str], end: float) -> None:
        """Close ``key``'s open gap at ``end`` (its first message on the new path), or at
        the end of the counted arrivals queued before it, if later; under ``_lock``."""
        gap = self._waiting.pop(key, None)
        self._limits.pop(key, None)
        end = max(end, self._counted_ahead.pop(key, end))
        if gap is not None:
            self._queue.append(MeasurementGap(end, gap.start, end, gap.reason, gap.topic))

    def _push(self, make: Callable[[float], Event | BlackBoxEvent]) -> None:
        with self._lock:
            if len(self._queue) < self._queue_limit:
                self._queue.append(make(self._wall()))
            else:
                self._dropped += 1

    def _report(self, kind: str, component: str, message: str) -> None:
        log.warning("%s: %s", component, message)
        with self._lock:
            now = self._wall()
            self._queue.append(BlackBoxEvent(now, f"ros1_{kind}", message, component))
            if kind == "master_lost" and self._master_gap is None:
                self._master_gap = MeasurementGap(
                    now, now, None, "ROS master unreachable: publishers that appear or "
                    "re-register are not followed", graph=True)
                self._queue.append(self._master_gap)
            elif kind == "master_back" and self._master_gap is not None:
                gap, self._master_gap = self._master_gap, None
                self._queue.append(MeasurementGap(now, gap.start, now, gap.reason, graph=True))

    def _graph_loop(self) -> None:
        next_resources = 0.0
        subscriber = self._subscriber
        assert subscriber is not None
        dead: set[str] = set()
        while not self._stop.is_set():
            started = time.time()
            try:
                self._expire_waiting(dead)
                interest = self._interest
                self._poller.refresh(self._bus.calls(interest.topics | interest.decoded,
                                                     self._poller.state.publishers, dead))
                self._push(self._poller.snapshot)
                dead = {n for n, st in self._poller.nodes.items() if not st.alive}
                publishers = self._poller.state.publishers
                self._count_rates(started, publishers, dead)
                self._follow_connections(publishers, dead)
                self._note_local_publishers(publishers, dead)
                if self.counted:
                    publishers = {t: tuple(n for n in nodes if (t, n) not in self.counted)
                                  for t, nodes in publishers.items()}
                subscriber.sync(publishers, self._poller.uri_of)
                subscriber.drop_half_open(dead, self._idle_grace)
                if started >= next_resources:
                    next_resources = started + self._resource_period
                    nodes = dict(self._poller.snapshot(started).nodes)
                    for sample in self._resources.sample(started, self._interest.resources,
                                                         nodes):
                        self._push(partial(_restamped, sample))
                    if self._interest.network:
                        self._sample_network(started)
            except Exception as exc:  # the graph thread must outlive any surprise
                log.exception("graph round failed")
                self._report("graph_error", self.master_uri, f"graph round failed: {exc!r}")
            self._last_round = started
            self._stop.wait(max(0.0, self._graph_period - (time.time() - started)))

    def _count_rates(self, now: float, publishers: dict[str, tuple[str, ...]],
                     dead: set[str]) -> None:
        """Arrivals from the publishers' counters for topics a live robot node subscribes
        to (their subscriptions are released); a subscribed topic the black box receives
        less of than an on-robot subscriber is reported as one it cannot keep up with."""
        assert self._subscriber is not None
        interest = self._interest
        rate_only = (interest.topics - interest.decoded if self.settings.rates_from_counters
                     else frozenset())
        results = self._bus.count(now, interest.topics | interest.decoded, publishers,
                                  self._poller.replies, dead)
        counted: set[tuple[str, str]] = set()
        for r in results:
            key = (r.topic, r.publisher)
            # the subscription is released only once counts can continue its arrivals
            # without a gap (a first reading gives no count yet)
            if r.topic in rate_only and r.on_robot and (key in self.counted
                                                        or r.robot_sent is not None):
                counted.add(key)
                switched = key not in self.counted
                if switched:
                    self._subscriber.release(StreamKey(r.topic, r.publisher),
                                             "rate from the publisher's counters")
                    self._report("rate_from_counters", r.topic,
                                 f"{r.topic} from {r.publisher}: rate from the publisher's "
                                 "own counters (getBusStats); not subscribed")
                span = r.arrivals[-1].time - now if r.arrivals else 0.0
                late = 2 * self._graph_period + self.settings.probe_timeout
                if not switched and span > late:
                    # a late round (the black box stalled): its counts cover a stretch
                    # nobody measured live; replayed, they would overlap the next round's
                    self._open_gap(key, f"a late round of the publisher's counters "
                                   f"({span:.3g} s) for {key[1]}", start=now - span)
                    self._counted_until.pop(key, None)
                    continue
                if not r.arrivals:  # a silent round: the next counts start afresh
                    self._counted_until.pop(key, None)
                self._push_counted(now, r.arrivals, key if switched else None)
            else:
                self._check_behind(now, r)
        for topic, node in self.counted - counted:
            if node not in dead:  # a dead publisher's silence is the robot's, not a gap
                self._switch_to_subscription((topic, node), now)
            why = self._bus.unavailable.get(node)
            self._report("rate_from_subscription", topic,
                         f"{topic} from {node}: "
                         + (f"the publisher's counters are unavailable ({why})" if why
                            else "no live subscriber on the robot")
                         + "; subscribing to measure its rate")
        self.counted = counted
        self._mark_counted(counted)

    def _note_local_publishers(self, publishers: dict[str, tuple[str, ...]],
                               dead: set[str]) -> None:
        """Record the live publishers of watched topics that run on this host, with their
        pids (their run-queue waits tell ``poll`` when the host starved them)."""
        watched = self._interest.topics | self._interest.decoded
        pids: dict[str, int] = {}
        topics: dict[str, tuple[str, ...]] = {}
        for topic in sorted(watched):
            for node in publishers.get(topic, ()):
                st = self._poller.nodes.get(node)
                if (st is None or node in dead or st.pid is None or not st.uri
                        or not is_local_host(host_of(st.uri))):
                    continue
                pids[node] = st.pid
                topics[node] = (*topics.get(node, ()), topic)
        self.starvation.local_publishers = (pids, topics)

    def _switch_to_subscription(self, key: tuple[str, str], round_start: float) -> None:
        """The gap of a counted topic whose on-robot subscriber is gone (the black box
        subscribes to measure it): the two paths' arrivals must neither leave a hole
        between them nor overlap.

        - It starts where the counted arrivals end, if that is before now, not when the
          round that found the subscriber gone ended: that round waited for the
          subscriber's probe (a stopped node: the whole probe time-out), and the stretch
          was the black box's blind spot, not the topic's silence (a provisional period).
          Without queued counts it starts at the round's start (``round_start``).
        - It lasts at least until the end of the counted arrivals already queued, when
          those run ahead of now (a round's counts are spread over the round after it, up
          to two rounds and a probe time-out ahead after slow rounds): ended at the first
          subscribed message, the rest of the counted arrivals came between the subscribed
          ones, a doubled rate for up to a second and a half (a too-fast ``hz``)."""
        with self._lock:
            end = self._counted_until.get(key)
            now = self._wall()
        start = round_start if end is None else min(end, now) - self.clock_offset
        self._open_gap(key, f"switching from the publisher's counters to a subscription "
                       f"for {key[1]}", start=start, ends_after=end)

    def _mark_counted(self, counted: set[tuple[str, str]]) -> None:
        """Record how far each counted topic is now counted (for :meth:`_await_counts`):
        to the end of its queued arrivals, which run a round ahead of now, or to now."""
        now = self._wall()
        with self._lock:
            until = dict(self._counted_until)
        with self._counts_done:
            self._covered = {k: max(until.get(k, now), now) for k in counted}
            self._counts_done.notify_all()

    def _check_behind(self, now: float, r: TopicCounts) -> None:
        if r.robot_sent is None or r.own_sent is None:
            return
        window = self._behind_counts.setdefault(r.topic, deque())
        window.append((now, r.robot_sent, r.own_sent))
        while window and window[0][0] < now - self.settings.behind_window:
            window.popleft()
        sent = sum(w[1] for w in window)
        got = sum(w[2] for w in window)
        behind = sent > 10 and got < (1.0 - self.settings.behind_tolerance) * sent
        if behind and r.topic not in self.behind:
            self.behind.add(r.topic)
            self._report("behind", r.topic,
                         f"cannot keep up with {r.topic}: the black box got {got} of the "
                         f"{sent} messages {r.publisher} sent an on-robot subscriber in the "
                         f"last {self.settings.behind_window:g} s; its rate as seen here is "
                         "the link's, not the robot's")
        elif not behind and r.topic in self.behind and got >= sent:
            self.behind.discard(r.topic)
            self._report("keeping_up", r.topic, f"keeping up with {r.topic} again")

    def _follow_connections(self, publishers: dict[str, tuple[str, ...]],
                            dead: set[str]) -> None:
        """Gaps of the black box's own connections (under the graph thread): a connection
        to a live publisher that closed since the last round (from that round until the
        reconnection delivers), and a publisher that re-registered under a new URI (a
        restarted node: from now until its new connection delivers). Released connections
        (rates from the counters) and dead publishers are no gap."""
        assert self._subscriber is not None
        connected = self._subscriber.connected()
        lost = self._connected - connected
        self._connected = connected
        uris = {n: st.uri for n, st in self._poller.nodes.items() if st.uri}
        moved = sorted(n for n, uri in uris.items() if self._uris.get(n, uri) != uri)
        self._uris = uris
        limit = self.settings.reconnect_limit
        for key in sorted(lost, key=lambda k: (k.topic, k.publisher)):
            if (key.publisher in dead or (key.topic, key.publisher) in self.counted
                    or key.publisher not in publishers.get(key.topic, ())):
                continue
            self._open_gap((key.topic, key.publisher), "reconnecting to "
                           f"{key.publisher}: the black box's connection closed",
                           start=self._last_round or None, limit=limit)
        watched = self._interest.topics | self._interest.decoded
        for node in moved:
            if node in dead:
                continue
            for topic in sorted(t for t in watched if node in publishers.get(t, ())):
                self._open_gap((topic, node), f"{node} re-registered (a new process at "
                               f"{uris[node]}); connecting to it", limit=limit)

    def _open_gap(self, key: tuple[str, str], reason: str, start: float | None = None,
                  limit: float | None = None, ends_after: float | None = None) -> None:
        """``key``'s rate is not measured from now (or ``start``, an earlier source time
        without ``clock_offset``) until its next message, subscribed or counted, at most
        ``limit`` s (``gap_limit``).

        A gap found out late (a round that waited for a probe) is stamped at its start, or
        at the last horizon ``poll`` handed out if that is later, not at "now": ``poll``
        then hands it out with the first horizon it reaches. Stamped "now", it was held
        back to the next horizon while the one it covered was judged on the silence.
        ``ends_after`` (source time): the gap does not end before it."""
        with self._lock:
            if key in self._waiting:
                return
            now = self._wall()
            begin = now if start is None else min(now, start + self.clock_offset)
            gap = MeasurementGap(max(begin, self._floor), begin, None, reason, topic=key[0])
            self._waiting[key] = gap
            if ends_after is not None and ends_after > now:
                self._counted_ahead[key] = ends_after
            if limit is not None:
                self._limits[key] = limit
            elif begin < now:  # ``gap_limit`` counts from the switch, not from ``start``
                self._limits[key] = self.settings.gap_limit + (now - begin)
            self._queue.append(gap)

    def _expire_waiting(self, dead: set[str]) -> None:
        """Close the gaps whose topic has not delivered within their limit (``gap_limit``
        or ``reconnect_limit`` s), and those whose publisher stopped answering: its silence
        from then on is the robot's."""
        with self._lock:
            now = self._wall()
            for key, gap in list(self._waiting.items()):
                limit = self._limits.get(key, self.settings.gap_limit)
                if key[1] in dead:
                    why = f"{key[1]} stopped answering, its silence is the robot's"
                elif now - gap.start >= limit:
                    why = f"no message within {limit:g} s, judging its silence again"
                else:
                    continue
                del self._waiting[key]
                self._limits.pop(key, None)
                end = max(now, self._counted_ahead.pop(key, now))
                self._queue.append(MeasurementGap(end, gap.start, end, f"{gap.reason}; {why}",
                                                  gap.topic))

    def _push_counted(self, round_start: float, arrivals: list[MessageArrival],
                      switched: tuple[str, str] | None = None) -> None:
        """Queue counted arrivals (stamped from ``round_start`` on) shifted to start at the
        instant they are queued, so nothing lands before an earlier ``poll`` horizon.

        ``switched``: the (topic, publisher) whose subscription was just released for these
        counts; the switch is a gap from now to the first counted arrival (the last
        subscribed messages and the first counts cover the same round).

        A round's counts cover the time since the previous round's, so they continue where
        the previous round's arrivals ended (or at the last time ``poll`` handed out, if
        that is later), unless that is more than two graph periods and a probe time-out
        ahead of now. Queued at "now", a round that waited longer for its replies (a
        stopped node's probe timing out, a busy machine) left a hole and a quick one after
        it laid its arrivals over the previous ones: a doubled rate for a moment, the
        false alarms of the real campaign on the other counted topic during a stall."""
        with self._lock:
            shift = self._wall() - round_start
            key = (arrivals[0].topic, arrivals[0].publisher) if arrivals else None
            if key is not None and switched is None:
                last = self._counted_until.get(key)
                start = round_start + shift  # where this round's interval begins: now
                ahead = 2 * self._graph_period + self.settings.probe_timeout
                if last is not None and last <= start + ahead:
                    shift += max(last, self._floor) - start
            if key is not None:
                self._counted_until[key] = arrivals[-1].time + shift
            if switched is not None:
                now = self._wall()
                self._resume(switched, now)  # a gap still open for the old path
                end = arrivals[0].time + shift if arrivals else now
                self._queue.append(MeasurementGap(
                    now, now, None, f"switching from a subscription to the publisher's "
                    f"counters for {switched[1]}", topic=switched[0]))
                self._queue.append(MeasurementGap(
                    end, now, end, f"switching from a subscription to the publisher's "
                    f"counters for {switched[1]}", topic=switched[0]))
            if arrivals and self._waiting:
                self._resume((arrivals[0].topic, arrivals[0].publisher),
                             arrivals[0].time + shift)
            for msg in arrivals:
                if len(self._queue) < self._queue_limit:
                    msg.time += shift
                    self._queue.append(msg)
                else:
                    self._dropped += 1

    def _sample_network(self, now: float) -> None:
        for iface, c in psutil.net_io_counters(pernic=True).items():
            self._push(partial(NetworkSample, interface=iface, rx_bytes=c.bytes_recv,
                               tx_bytes=c.bytes_sent))


def _restamped(sample: ResourceSample, time: float) -> ResourceSample:
    return dataclasses.replace(sample, time=time)


def open_ros1_source(spec: str, options: SourceOptions) -> Ros1Source:
    return Ros1Source.from_uri(spec)


SOURCES.add("ros1", SourceKind("ros1", open_ros1_source, ROS1_CAPABILITIES,
                               "ros1 or ros1://HOST:PORT[?caller_id=/NAME&counters=0"
                               "&readers=N&coalesce=SECONDS] (readers: child processes "
                               "reading timing-only topics, default 0 = a thread; "
                               "coalesce: read busy topics at most every SECONDS, "
                               "default 0)"))
