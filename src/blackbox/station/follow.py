"""The station side of DDS: follows every robot on a domain and keeps it in the station store.

One :class:`StationFollower` joins the domain (one participant, loopback unless configured),
reads every UCMS and extension topic, and writes what it hears into a
:class:`~blackbox.station.store.StationStore`. It trusts nothing it receives: each sample is
handled on its own, strings and sequences are clipped, non-finite values are skipped, and a
sample that cannot be interpreted is counted and listed in the store's problems.

Samples from a resource id that no ``BlackBox_Entity_Description`` has named (an unknown
robot id) are held back for :attr:`StationFollower.identify_within` seconds and stored as
soon as the robot names itself; otherwise they are dropped and reported. A description that
names a robot whose id does not hash to the sample's resource id is refused.

Nothing is lost across a station restart: durable state (entities, characteristics,
thresholds) comes back from the robots' transient-local writers, and on first sight of
each robot a log request (:meth:`_fetch_log`) fetches the exceedances, failures and
announced changes of state recorded since the station last heard it (at most ``backfill``
seconds back). An event fetched from the log and the same event heard live have the same
key in the store, so neither path duplicates the other.

Operations for the web (``request_logs``, ``run_ibit``) return at once with a record id and
run on a worker thread; their progress and results are in the store.

Robots the station enrolled (``robot_keys``, :mod:`blackbox.station.enrolment`) are
authenticated end to end: every sample passes :class:`~blackbox.station.trust.SampleGate`
(only what the robot signed is shown), log replies and IBIT results count only with the
robot's signature, and two participants writing for one robot are flagged.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.util import duration

from blackbox.errors import BlackBoxError
from blackbox.health.extension import (
    C_Characteristic_Extension,
    C_Entity_Description,
    C_Event_Extension,
    T_EventKind,
)
from blackbox.health.identity import EventId
from blackbox.health.ids import robot_resource_id
from blackbox.health.types import (
    C_Failure_Event,
    C_Monitored_Characteristic,
    C_Monitored_Characteristic_Specification,
    C_Monitored_Entity,
    C_Threshold,
    C_Threshold_Exceedence_Event,
    T_IdentifierType,
    T_Monitored_Entity_StateType,
    T_ThresholdType,
    datetime_of,
    seconds_of,
)
from blackbox.record.store import KINDS, LogEntry
from blackbox.station.claims import BootWatch
from blackbox.station.clocks import ClockWatch
from blackbox.station.coalesce import newest_per_characteristic
from blackbox.station.delivery import DeliveryWatch
from blackbox.station.enrolment import RobotKeys
from blackbox.station.sequence import EventSequences, Gap
from blackbox.station.store import (
    STATUSES,
    RobotRef,
    StationStore,
    StationStoreError,
    UnknownRobot,
    explain,
    robot_resource,
)
from blackbox.station.trust import SampleGate, WriterWatch
from blackbox.station.wording import rectified, unnamed_entity
from blackbox.transport.auth import RequestSigner, public_key_text
from blackbox.transport.buses import open_bus
from blackbox.transport.logservice import LogAnswer, LogClient
from blackbox.transport.participant import HealthBus, TransportSettings, Waiter
from blackbox.transport.provenance import SIGNATURE_TOPIC
from blackbox.transport.qos import EVENT_TOPICS, qos_for

log = logging.getLogger("blackbox.station")

FOLLOWED = ("C_Monitored_Entity", "C_Monitored_Characteristic",
            "C_Monitored_Characteristic_Specification", "C_Threshold",
            "C_Threshold_Exceedence_Event", "C_Failure_Event", "BlackBox_Entity_Description",
            "BlackBox_Characteristic_Extension", "BlackBox_Event_Extension")
"""Topics the station reads (all published UCMS topics plus the extension topics)."""

BACKFILL_KINDS = ("exceedance", "failure", "observation")
"""Log kinds a backfill fetches: every kind a numbered event is logged as. Faults start as
``exceedance`` rows, failures and rectifications are named on ``failure`` rows, and a
change of state the robot announced (a numbered ``state_change`` event) is an
``observation`` row carrying its ``event_id``: without it such an event missed live would
be reported lost although the robot's log has it."""
MAX_STRING = 2000
MAX_IDS = 1000
MAX_LOG_ROWS = 200_000
LOG_PAGE = 2000
MAX_LOG_RANGE_DAYS = 3660
EXT_WAIT = 1.0
"""Seconds an event waits for its extension (its identity, on another topic) once the
extension reader has nothing more queued."""
EXT_WAIT_MAX = 30.0
"""Seconds an event waits for its extension at most, even while the extension reader is
behind (a flood must not hold events, or memory, for ever): then it is stored under its
time key."""
MAX_WAITING = 100_000
"""Events (and inferred rectifications) waiting for extensions at most; beyond, the oldest
is stored without one."""
MAX_UNNAMED = 20_000
"""Events stored without their identity that are remembered, so that an identity arriving
late can still be matched to its row (the oldest are forgotten first)."""
EXTENSION_TOPIC = "BlackBox_Event_Extension"
BACKFILL_REPEAT = 5.0
STATE_DEPTH = 64
TAKE = 2048
"""Samples taken from one reader per poll; a full take means more were waiting. 512 held
a station that polls every :data:`POLL_EVERY` s under 10,240 values a second, less than
1,000 robots send."""
VALUES_TOPIC = "C_Monitored_Characteristic"
COALESCE_TAKE = 200_000
"""Values taken at most at once from a backlog to be coalesced (the bus's queue holds
100,000 per topic)."""
POLL_EVERY = 0.05
"""Seconds between the starts of two polls at least. Samples arriving one by one made a
poll, a commit and a walk over every robot's event numbers per sample (a hundred a
second with 200 robots); 50 ms adds at most that to a colour change on the page."""
_ON = T_Monitored_Entity_StateType.L_Monitored_Entity_StateType_ON
_ORDER = {"BlackBox_Entity_Description": 0, EXTENSION_TOPIC: 1,
          "C_Failure_Event": 2}


class StationBusy(BlackBoxError, RuntimeError):
    """Too many log requests and built-in tests are waiting; try again later."""


def _items(value: Any) -> list[Any]:
    """The elements of an IDL sequence field (typed ``sequence``, which mypy cannot see
    through)."""
    return list(value)


def _key(ident: T_IdentifierType) -> tuple[int, int]:
    return (int(ident.A_resourceId), int(ident.A_instanceId))


def _stamp(t: float) -> str:
    """Event times in dedup keys: milliseconds, so the float that went through UCMS's
    seconds + nanoseconds and the one the recorder stored give the same key."""
    return f"{t:.3f}"


def _instant(t: float) -> str:
    """A robot's time to the nanosecond, as its UCMS samples carry it (seconds and
    nanoseconds): the time a sample decodes to and the float the robot's recorder stored
    give the same text (``seconds_of(datetime_of(t)) == t`` for the robot's clock
    readings). A time that is no number (from a malformed log reply) is kept as it is."""
    if not math.isfinite(t):
        return str(t)
    dt = datetime_of(t)
    return f"{dt.A_second}.{dt.A_nanoseconds:09d}"


def _diagnosis_key(t: float, components: frozenset[str]) -> str:
    """The dedup key of a diagnosis the station derives itself. The robot numbers the
    failures and rectifications a diagnosis causes, not the diagnosis, so it is keyed by
    the robot's time of it to the nanosecond (the resolution at which the robot's event
    ledger tells events apart) and its components: every change of the robot's diagnosis
    stays, also many in one millisecond (a flapping component; keyed by the millisecond
    they merged, and the newest diagnosis row could contradict the robot's current one),
    while the live and the logged copy of one diagnosis meet."""
    return f"diagnosis|{_instant(t)}|{','.join(sorted(components))}"


def _primary(resource_label: str) -> str:
    """The recorder's entity of a resource label (``Resource.label()``): node, topic or
    interface, as ``blackbox.record.policy.entity_of`` names it."""
    parts = resource_label.split(" ")
    if parts[0] == "iface" and len(parts) > 1:
        return parts[1]
    return parts[0]


@dataclass(slots=True)
class _Entity:
    name: str = ""
    kind: str = ""
    failures: int = 0
    cause: str = ""


@dataclass(slots=True)
class _Char:
    name: str = ""
    observer: str = ""
    resource: str = ""
    entity: int | None = None
    last_sample: tuple[float, float] | None = None
    """The robot's time and value of the last sample taken: a durable sample delivered again
    (a reader that matched the robot anew) is not a new chart point."""
    exceeded: bool | None = None
    """Whether the last value taken named an active exceedance (``None``: not yet known in
    this run), so the flag is written when it changes, not with every value."""


@dataclass(slots=True)
class _Robot:
    resource_id: int
    robot_id: str = ""
    entities: dict[int, _Entity] = field(default_factory=dict)
    chars: dict[int, _Char] = field(default_factory=dict)
    diagnosis: frozenset[str] = frozenset()
    seen: set[int] = field(default_factory=set)
    last_heard_before: float | None = None
    backfill_since: float | None = None
    backfill_due: list[float] = field(default_factory=list)
    held: list[tuple[float, Any]] = field(default_factory=list)
    first_held: float | None = None
    sends_ids: bool = False
    """The robot names its events (``<boot>-<sequence>``): the station then stores its
    rectifications as the robot announces them instead of inferring them."""
    sequences: EventSequences = field(default_factory=EventSequences)
    gap_fetch: bool = False
    unnamed_events: set[int] = field(default_factory=set)
    """Entities that events were stored for under their id (``#<id>``): their
    description has not come yet (:meth:`StationFollower._name_entity_events`)."""

    @property
    def name(self) -> str:
        return self.robot_id or f"#{self.resource_id}"


@dataclass(frozen=True, slots=True)
class _InferredRectification:
    """An entity whose failures went to none, of a robot not (yet) seen naming its events:
    a rectification unless the robot turns out to announce its own (extensions late)."""

    arrived: float
    resource_id: int
    time: float
    entity: str


@dataclass(frozen=True, slots=True)
class _EventRow:
    """A failure or exceedance as the store takes it (``add_event``'s arguments)."""

    time: float
    kind: str
    dedup: str
    entity: str
    characteristic: str
    text: str
    details: dict[str, Any]


@dataclass(frozen=True, slots=True)
class _Unnamed:
    """An event stored under its time key because its identity had not come (yet): kept so
    that the identity, arriving late, re-keys that row instead of a second copy being made
    once the robot's log supplies the event under its identity."""

    sample: C_Threshold_Exceedence_Event | C_Failure_Event
    dedup: str


@dataclass(slots=True)
class _Lane:
    """A worker thread with its own job queue and log client: operators' requests and the
    automatic backfill run in separate lanes, so an unreachable robot's backfill never
    makes an operator's log request wait."""

    name: str
    jobs: queue.Queue[Callable[[], None] | None] = field(
        default_factory=lambda: queue.Queue(maxsize=64))
    client: LogClient | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)


@dataclass(slots=True)
class FollowerStats:
    received: int = 0
    rejected: int = 0
    held: int = 0
    dropped_unknown: int = 0
    backfilled: int = 0
    events_lost: int = 0
    """Events a robot numbered that were neither received nor found in its log."""
    by_topic: dict[str, int] = field(default_factory=dict)


class StationFollower:
    """Follows every robot on one DDS domain/partition into ``store``.

    ``backfill``: on first sight of a robot, fetch its recorded events (``BACKFILL_KINDS``)
    since the station last heard it, at most this many seconds back (0 = never).
    ``station_id``: names this station in log requests.
    ``start()`` opens the participant and starts the reading and the worker threads;
    ``stop()`` ends both and closes the participant (the store stays open: close it
    yourself). For a single-threaded caller, ``open()`` then ``poll()`` in a loop works too.
    """

    identify_within = 10.0
    """Seconds samples of a not yet named resource id are held before they are dropped."""

    def __init__(self, store: StationStore, settings: TransportSettings | None = None, *,
                 backfill: float = 3600.0, station_id: str = "station",
                 log_timeout: float = 10.0, log_page: int = LOG_PAGE,
                 max_log_rows: int = MAX_LOG_ROWS, ibit_timeout: float = 15.0,
                 signer: RequestSigner | None = None,
                 robot_keys: RobotKeys | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        self.store = store
        self.settings = settings or TransportSettings()
        self.backfill = max(0.0, backfill)
        self.station_id = station_id
        self.log_timeout = log_timeout
        self.log_page = max(1, log_page)
        self.max_log_rows = max(1, max_log_rows)
        self.ibit_timeout = ibit_timeout
        self.signer = signer
        """Signs log requests and IBIT commands (robots answer only stations they list);
        ``None``: the key named by ``$BLACKBOX_STATION_KEY``, if set, else unsigned."""
        self.clock = clock
        self.stats = FollowerStats()
        self.robot_keys = robot_keys
        """The robots this station trusts (``None``: none; every robot unauthenticated)."""
        self.gate = SampleGate(robot_keys.by_resource if robot_keys is not None else dict,
                               self._trust_problem, on_key_seen=self._key_seen)
        self.writers = WriterWatch()
        self.delivery = DeliveryWatch(store.report_problem, store.clear_problem)
        """Samples the bus dropped and whether the station keeps up (problems, /metrics)."""
        self.clocks = ClockWatch(store.report_problem, store.clear_problem)
        """Robots whose clock is minutes off: their events go at the station's time."""
        self.boots = BootWatch(store.report_problem)
        """Robot ids two black boxes use at once (their boots interleave)."""
        self._participants: dict[tuple[int, Any], str] = {}
        self._signature_reader: DataReader[Any] | None = None
        self.bus: HealthBus | None = None
        self._readers: dict[str, Any] = {}
        self._waitset: Waiter | None = None
        self._robots: dict[int, _Robot] = {}
        self._ext: dict[tuple[int, int], C_Event_Extension] = {}
        self._unnamed: OrderedDict[tuple[int, int], _Unnamed] = OrderedDict()
        """Events stored under their time key, by source id (see :class:`_Unnamed`)."""
        self._time_keys: OrderedDict[tuple[int, str], tuple[tuple[int, int], float]] = \
            OrderedDict()
        """Which event owns the row stored under a time key (robot, key -> its source id
        and robot time): events of one millisecond share a key, and only the owner's
        identity, arriving late or with the logged copy, may take that row (the backfill
        thread reads it: guarded by ``_time_keys_lock``)."""
        self._time_keys_lock = threading.Lock()
        self._waiting: list[tuple[float, C_Threshold_Exceedence_Event | C_Failure_Event]] = []
        """Events waiting for their extension, which travels on another topic (see
        :meth:`_extension_overdue`)."""
        self._inferred: list[_InferredRectification] = []
        self._extensions_drained = -math.inf
        """When the extension reader last had nothing more queued (a take below ``TAKE``):
        an extension not taken by then had not arrived."""
        self._sequence_lock = threading.Lock()
        self._requests = _Lane("requests")
        self._backfills = _Lane("backfill")
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._bus_lock = threading.Lock()

    # ---- life cycle -------------------------------------------------------------------------

    def open(self) -> None:
        """Join the domain and create the readers (``start`` does this itself)."""
        if self.bus is not None:
            return
        self._load_known()
        self.bus = open_bus(self.settings, self.station_id)
        self._readers = {name: self._reader(name) for name in FOLLOWED}
        self._signature_reader = self._reader(SIGNATURE_TOPIC)
        self._waitset = self.bus.waiter([*self._readers.values(), self._signature_reader])
        for lane in (self._requests, self._backfills):
            lane.client = LogClient(self.bus, self.station_id, signer=self.signer)

    def _reader(self, name: str) -> Any:
        """A reader with the topic's QoS, but a deeper history for state topics: the
        writers keep only the latest sample per instance, and a station that takes
        samples every fraction of a second must still see a failure and its
        rectification that came between two takes."""
        assert self.bus is not None
        qos = qos_for(name)
        if name not in EVENT_TOPICS:
            qos = Qos(Policy.Durability.TransientLocal, Policy.History.KeepLast(STATE_DEPTH),
                      Policy.Reliability.Reliable(duration(seconds=1)))
        return self.bus.reader(name, qos)

    def start(self) -> None:
        """Open, then follow on a background thread until :meth:`stop`; the store writes on
        a thread of its own meanwhile (:meth:`StationStore.start_writer`), so taking
        samples never waits on the database."""
        self.open()
        self.store.start_writer()
        self._stop.clear()
        self._threads = [threading.Thread(target=self._follow, name="station-follow",
                                          daemon=True),
                         *(threading.Thread(target=self._work, args=(lane,),
                                            name=f"station-{lane.name}", daemon=True)
                           for lane in (self._requests, self._backfills))]
        for t in self._threads:
            t.start()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        for lane in (self._requests, self._backfills):
            with contextlib.suppress(queue.Full):
                lane.jobs.put_nowait(None)
        for t in self._threads:
            t.join(timeout=timeout)
        self._threads = []
        self.store.stop_writer()
        self.store.flush(force=True)
        with self._bus_lock:
            if self.bus is not None:
                self.bus.close()
                self.bus = None

    def __enter__(self) -> StationFollower:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _load_known(self) -> None:
        """What the store knew before this run: names, failures, when each robot was heard."""
        for summary in self.store.fleet():
            robot = self._robot(summary.resource_id)
            robot.robot_id = summary.robot_id
            robot.last_heard_before = summary.last_heard
            robot.diagnosis = frozenset(summary.diagnosis)
            with contextlib.suppress(UnknownRobot):
                for e in self.store.entities(summary.resource_id):
                    robot.entities[e.instance_id] = _Entity(e.name, e.kind, e.failures)
                for c in self.store.characteristics(summary.resource_id):
                    robot.chars[c.instance_id] = _Char(c.name, c.observer, c.resource,
                                                       c.entity)

    def _follow(self) -> None:
        started = -math.inf
        while not self._stop.is_set():
            # a poll has costs of its own (a commit, a look at every robot's event
            # numbers): a busy fleet's samples are taken in batches, not one by one
            if self._stop.wait(max(0.0, started + POLL_EVERY - time.monotonic())):
                return
            started = time.monotonic()
            try:
                self.poll(0.2)
            except Exception as exc:  # keep following whatever one cycle did
                log.exception("station: follow cycle failed")
                self.store.report_problem("dds", f"follow cycle failed: {exc}")
                time.sleep(0.2)

    # ---- reading ---------------------------------------------------------------------------

    def poll(self, timeout: float = 0.2) -> int:
        """Wait up to ``timeout`` s for samples, handle all, flush the store; returns the
        number of samples taken."""
        assert self._waitset is not None, "open() first"
        self._waitset.wait(timeout)
        now = self.clock()
        started = time.monotonic()
        self._take_signatures()
        taken: list[tuple[str, Any]] = []
        behind: set[str] = set()
        for name, reader in self._readers.items():
            try:
                samples = reader.take(N=TAKE)
            except Exception as exc:
                self._reject(name, f"cannot read: {exc}")
                continue
            coalesce = False
            if len(samples) >= TAKE:
                behind.add(name)
                if name == VALUES_TOPIC and self.delivery.behind:
                    samples = self._backlog(reader, samples)
                    coalesce = True
            admitted = []
            for sample in samples:
                info = getattr(sample, "sample_info", None)
                if info is not None and not info.valid_data:
                    continue
                if self._admit(name, reader, sample, now):
                    admitted.append(sample)
            if coalesce:
                admitted = self._coalesce(admitted)
            taken.extend((name, sample) for sample in admitted)
        taken.extend(self.gate.released(now))
        self.ingest(taken, now, behind=behind)
        self._drop_foreign_replies()
        self.store.flush_soon()  # on the store's writer thread once start() started it
        self._start_backfills()
        self.delivery.check(self._readers, now)
        self.delivery.took(bool(behind), now, time.monotonic() - started)
        return len(taken)

    def _backlog(self, reader: Any, samples: list[Any]) -> list[Any]:
        """``samples`` and the rest of the values reader's backlog (to be coalesced)."""
        try:
            return [*samples, *reader.take(N=COALESCE_TAKE)]
        except Exception as exc:
            self._reject(VALUES_TOPIC, f"cannot read: {exc}")
            return samples

    def _coalesce(self, values: list[Any]) -> list[Any]:
        """The newest of each characteristic of admitted ``values`` (the station has been
        behind for a while: see :mod:`blackbox.station.coalesce`); the older ones are
        counted and reported."""
        kept, left_out = newest_per_characteristic(values)
        if left_out:
            self.delivery.coalesced += left_out
            self.store.report_problem(
                "coalesced", f"the station is behind: {self.delivery.coalesced} "
                             "characteristic values left out so far for a newer value of "
                             "the same characteristic (charts thinned; events and statuses "
                             "are all kept)")
        return kept

    def ingest(self, taken: Sequence[tuple[str, Any]], now: float, *,
               behind: Collection[str] = ()) -> None:
        """Handle one poll's samples (``(topic, sample)``, admitted by the gate) taken at
        ``now``; ``behind`` names the topics whose reader held more than one take.
        :meth:`poll` reads them from DDS; kept apart so the bookkeeping of one batch
        (events waiting for their extensions, holes in a robot's numbers) can be driven
        batch by batch."""
        # Names and event extensions first: the samples they describe may come in the
        # same batch.
        taken = sorted(taken, key=lambda item: _ORDER.get(item[0], 3))
        if EXTENSION_TOPIC not in behind:
            self._extensions_drained = now
        heard: set[int] = set()
        for name, sample in taken:
            self.stats.by_topic[name] = self.stats.by_topic.get(name, 0) + 1
            try:
                rid = int(sample.A_sourceID.A_resourceId)
                if self._accept(rid, sample, now):
                    heard.add(rid)
                self.stats.received += 1
            except Exception as exc:
                self._reject(name, f"sample not understood: {type(exc).__name__}: {exc}")
        for rid in heard:
            self.store.heard(rid, now)
        self._resolve_waiting(now)
        self._check_sequences(now)
        self._expire_held(now)

    # ---- authentication -------------------------------------------------------------------

    def _take_signatures(self) -> None:
        reader = self._signature_reader
        if reader is None:
            return
        try:
            signatures = reader.take(N=4096)
        except Exception as exc:
            self._reject(SIGNATURE_TOPIC, f"cannot read: {exc}")
            return
        for sig in signatures:
            info = getattr(sig, "sample_info", None)
            if info is not None and not info.valid_data:
                continue
            try:
                self.gate.signature(sig)
            except Exception as exc:
                self._reject(SIGNATURE_TOPIC, f"signature not understood: {exc}")

    def _admit(self, name: str, reader: DataReader[Any], sample: Any, now: float) -> bool:
        """Whether ``sample`` may be handled now: the writer check, then the gate."""
        try:
            rid = int(sample.A_sourceID.A_resourceId)
            info = getattr(sample, "sample_info", None)
            if info is not None:
                participant = self._participant_of(reader, info.publication_handle)
                if participant:
                    other = self.writers.saw(rid, participant, now,
                                             lambda p: self._alive(reader, p))
                    if other is not None:
                        self._two_writers(rid, participant, other)
            return self.gate.offer(name, sample, now)
        except Exception as exc:
            self._reject(name, f"sample not understood: {type(exc).__name__}: {exc}")
            return False

    def _participant_of(self, reader: DataReader[Any], handle: Any) -> str:
        key = (id(reader), handle)
        found = self._participants.get(key)
        if found is None:
            data = reader.get_matched_publication_data(handle)
            found = str(data.participant_key) if data is not None else ""
            if len(self._participants) > 10_000:
                self._participants.clear()
            self._participants[key] = found
        return found

    def _alive(self, reader: DataReader[Any], participant: str) -> bool:
        for handle in reader.get_matched_publications():
            if self._participant_of(reader, handle) == participant:
                return True
        return False

    def _two_writers(self, rid: int, participant: str, other: str) -> None:
        self.gate.stats.second_writers += 1
        robot = self._robots.get(rid)
        enrolled = self.gate.enrolled(rid)
        name = enrolled[0] if enrolled else robot.name if robot is not None else f"#{rid}"
        self.store.report_problem(
            f"two writers {name}",
            f"{name}: two DDS participants write under this robot's id at once "
            f"({other[:8]}... and {participant[:8]}...)"
            + ("; only what the robot signed is shown" if enrolled else
               "; the robot is not enrolled, so its health cannot be told from a forgery"))

    def _trust_problem(self, robot_id: str, kind: str, message: str) -> None:
        self.store.report_problem(f"{kind} data {robot_id}", message)

    def _key_seen(self, robot_id: str, key: Any) -> None:
        if self.robot_keys is None:
            return
        self.robot_keys.note_seen(robot_id, key)
        keys = {k.public_key for k in self.robot_keys.seen() if k.robot_id == robot_id}
        if len(keys) > 1:
            self.gate.stats.second_writers += 1
            self.store.report_problem(
                f"two writers {robot_id}",
                f"{robot_id}: signatures with {len(keys)} different keys claim this robot; "
                "enrol the right one from the robot's key file (robots enrol --key)")
        self.store.report_problem(
            f"not enrolled {robot_id}",
            f"{robot_id} signs its health with key {public_key_text(key)} but is not "
            f"enrolled: its data is shown unauthenticated. Check the key on the robot, "
            f"then: blackbox station robots enrol {robot_id} --seen")

    def _robot_key(self, robot_id: str) -> Any:
        enrolled = self.gate.enrolled(robot_resource_id(robot_id))
        return enrolled[1] if enrolled is not None and enrolled[0] == robot_id else None

    def _reject(self, topic: str, message: str) -> None:
        self.stats.rejected += 1
        log.warning("station: %s: %s", topic, message)
        self.store.report_problem(f"dds {topic}", message)

    def _robot(self, rid: int) -> _Robot:
        robot = self._robots.get(rid)
        if robot is None:
            robot = self._robots[rid] = _Robot(rid)
        return robot

    def _accept(self, rid: int, sample: Any, now: float) -> bool:
        """Handle ``sample`` now if its robot is named, else hold it; ``True`` if handled."""
        robot = self._robot(rid)
        if isinstance(sample, C_Entity_Description):
            self._description(robot, sample)
        if not robot.robot_id:
            if len(robot.held) < 10_000:
                robot.held.append((now, sample))
                self.stats.held += 1
            else:
                self.stats.dropped_unknown += 1
            if robot.first_held is None:
                robot.first_held = now
            return False
        if robot.held:
            held, robot.held, robot.first_held = robot.held, [], None
            for _, s in held:
                self._handle(robot, s, now)
        self._handle(robot, sample, now)
        return True

    def _expire_held(self, now: float) -> None:
        for robot in list(self._robots.values()):
            if robot.robot_id or robot.first_held is None:
                continue
            if now - robot.first_held >= self.identify_within:
                n = len(robot.held)
                self.stats.dropped_unknown += n
                del self._robots[robot.resource_id]  # a flood of ids must not grow memory
                self.store.report_problem(
                    "unknown robot", f"resource id {robot.resource_id}: {n} samples ignored: "
                    "no robot named itself with this id (no BlackBox_Entity_Description)")

    def _description(self, robot: _Robot, s: C_Entity_Description) -> None:
        claimed = s.A_robotId
        if s.A_kind == "robot" or (claimed and not robot.robot_id):
            if not claimed or len(claimed) > 200 or robot_resource_id(claimed) != \
                    robot.resource_id:
                self.store.report_problem(
                    "unknown robot", f"resource id {robot.resource_id}: a description claims "
                    f"robot id {claimed[:80]!r}, which does not belong to this resource id; "
                    "ignored")
                return
            if claimed != robot.robot_id:
                robot.robot_id = claimed
                self.store.put_robot_id(robot.resource_id, claimed)

    def _handle(self, robot: _Robot, s: Any, now: float) -> None:
        rid = robot.resource_id
        if isinstance(s, C_Entity_Description):
            iid = int(s.A_sourceID.A_instanceId)
            e = robot.entities.setdefault(iid, _Entity())
            was_unnamed = iid in robot.unnamed_events or e.name == unnamed_entity(iid)
            e.name = self._text(s.A_name, "entity name", 200)
            e.kind = self._text(s.A_kind, "entity kind", 20)
            parent = s.A_parent_sourceID
            self.store.put_entity(rid, iid, name=e.name, kind=e.kind,
                                  parent=int(parent.A_instanceId)
                                  if int(parent.A_resourceId) == rid else None,
                                  updated=seconds_of(s.A_timeOfDataGeneration))
            if was_unnamed and e.name:
                robot.unnamed_events.discard(iid)
                self._name_entity_events(rid, iid, e.name)
        elif isinstance(s, C_Monitored_Entity):
            self._entity(robot, s, now)
        elif isinstance(s, C_Monitored_Characteristic):
            iid = int(s.A_sourceID.A_instanceId)
            c = robot.chars.setdefault(iid, _Char())
            ent = s.A_monitoredEntity_sourceID
            if int(ent.A_resourceId) == rid:
                c.entity = int(ent.A_instanceId)
            value = float(s.A_value)
            robot_time = seconds_of(s.A_timeOfDataGeneration)
            self.clocks.observe(robot.name, robot_time, now)
            if c.last_sample != (robot_time, value):
                c.last_sample = (robot_time, value)
                self.store.put_value(rid, iid, self.clocks.time_of(robot.name, robot_time, now),
                                     value, c.entity)
            exceeded = bool(s.A_thresholdExceedenceEvents_sourceID)
            if c.exceeded is not exceeded:
                c.exceeded = exceeded
                self.store.put_characteristic(rid, iid, exceeded=exceeded)
        elif isinstance(s, C_Monitored_Characteristic_Specification):
            for ident in _items(s.A_specifiedCharacteristics_sourceID)[:16]:
                if int(ident.A_resourceId) != rid:
                    continue
                c = robot.chars.setdefault(int(ident.A_instanceId), _Char())
                if not c.name:
                    c.name = self._text(s.A_descriptor, "descriptor", 200)
                self.store.put_characteristic(rid, int(ident.A_instanceId),
                                              unit=self._text(s.A_unit, "unit", 20),
                                              name=c.name)
        elif isinstance(s, C_Characteristic_Extension):
            iid = int(s.A_sourceID.A_instanceId)
            c = robot.chars.setdefault(iid, _Char())
            c.name = self._text(s.A_name, "characteristic name", 200)
            c.observer = self._text(s.A_observer, "observer", 60)
            c.resource = self._text(s.A_resource, "resource", 200)
            noise = float(s.A_expectedNoise)
            self.store.put_characteristic(rid, iid, name=c.name, observer=c.observer,
                                          resource=c.resource,
                                          quantity=self._text(s.A_quantity, "quantity", 60),
                                          expected_noise=noise if math.isfinite(noise)
                                          else None)
        elif isinstance(s, C_Threshold):
            concerned = s.A_concernedCharacteristic_sourceID
            if int(concerned.A_resourceId) == rid:
                self.store.put_threshold(
                    rid, int(s.A_sourceID.A_instanceId), int(concerned.A_instanceId),
                    self._text(s.A_name, "threshold name", 60),
                    "min" if s.A_type == T_ThresholdType.L_ThresholdType_MIN else "max",
                    float(s.A_value))
        elif isinstance(s, C_Event_Extension):
            if s.A_eventId:
                robot.sends_ids = True
            if s.A_kind == T_EventKind.L_EventKind_RECTIFICATION:
                self._rectification(robot, s, now)
            else:
                unnamed = self._unnamed.pop(_key(s.A_sourceID), None)
                if unnamed is not None:
                    self._name_late(robot, unnamed, s, now)
                    return
                self._ext[_key(s.A_sourceID)] = s
                while len(self._ext) > 10_000:
                    self._ext.pop(next(iter(self._ext)))
        elif isinstance(s, C_Threshold_Exceedence_Event | C_Failure_Event):
            self._waiting.append((now, s))
        else:
            raise TypeError(f"unexpected sample {type(s).__name__}")

    def _text(self, value: str, what: str, limit: int = MAX_STRING) -> str:
        if len(value) > limit:
            self.store.report_problem("oversized sample", f"{what} of {len(value)} characters "
                                                          f"clipped to {limit}")
            return value[:limit]
        return value

    def _entity(self, robot: _Robot, s: C_Monitored_Entity, now: float) -> None:
        rid = robot.resource_id
        iid = int(s.A_sourceID.A_instanceId)
        e = robot.entities.setdefault(iid, _Entity())
        raw = int(s.A_healthStatus.value)
        status = STATUSES[raw] if 0 <= raw < len(STATUSES) else "UNKNOWN"
        online = s.A_MonitoredEntityState == _ON
        failures = len(_items(s.A_failureEvents_sourceID))
        t = seconds_of(s.A_timeOfDataGeneration)
        chars = [int(i.A_instanceId)
                 for i in _items(s.A_monitoredCharacteristics_sourceID)[:MAX_IDS]
                 if int(i.A_resourceId) == rid]
        self.store.put_entity(rid, iid, status=status, online=online,
                              bit=bool(s.A_bitInProgress), failures=failures,
                              characteristics=chars, updated=t)
        if e.kind == "robot":
            self.store.put_robot_online(rid, online)
        # The first sample of an entity in this run may be durable state from before: it
        # updates the state, while what happened meanwhile comes from the backfill.
        first = iid not in robot.seen
        robot.seen.add(iid)
        component = e.kind not in ("robot", "") and bool(e.name)
        if component and not first and e.failures > 0 and failures == 0 and online \
                and not robot.sends_ids:
            # Stored once it is clear the robot does not announce rectifications itself
            # (its extensions may be behind this state sample): _resolve_waiting.
            self._inferred.append(_InferredRectification(now, rid, t, e.name))
        e.failures = failures
        if component and online:
            self._set_diagnosis(robot, frozenset(x.name for x in robot.entities.values()
                                                 if x.kind not in ("robot", "")
                                                 and x.failures > 0 and x.name), t,
                                "live", event=not first)

    def _set_diagnosis(self, robot: _Robot, components: frozenset[str], t: float,
                       origin: str, explanation: str = "", event: bool = True) -> None:
        if components == robot.diagnosis:
            return
        robot.diagnosis = components
        rid = robot.resource_id
        self.store.put_diagnosis(rid, sorted(components), t if components else None)
        if not event:
            return
        causes = {e.name: e.cause for e in robot.entities.values()
                  if e.name in components and e.cause}
        text = explain(robot.name, sorted(components), causes, {})
        if explanation:
            text += f" Explanation: {explanation}"
        self.store.add_event(rid, t, "diagnosis", dedup=_diagnosis_key(t, components),
                             text=text, origin=origin,
                             details={"components": sorted(components)})

    def _identity(self, robot: _Robot, event_id: object, legacy: str, t: float,
                  now: float, live: bool = True) -> str:
        """The dedup key of an event, live or from the log: its identity when the robot named
        it (and the station notes the number as received), else the legacy key from kind,
        time and entity. ``event_id`` comes from the network or a log: parsed strictly."""
        ident = EventId.parse(event_id) if isinstance(event_id, str) else None
        if ident is None:
            return legacy
        with self._sequence_lock:
            robot.sequences.see(ident, t, now)
        if live:
            self.boots.see(robot.name, ident.boot)
        return f"id:{ident}"

    @staticmethod
    def _entity_name(robot: _Robot, e: _Entity | None, iid: int) -> str:
        """What an event of entity ``iid`` (``e``, known or not) is stored under: its name,
        or before its description came its id, remembered to be renamed then."""
        if e is not None and e.name:
            return e.name
        robot.unnamed_events.add(iid)
        return unnamed_entity(iid)

    def _name_entity_events(self, rid: int, iid: int, name: str) -> None:
        """The events stored before entity ``iid``'s description came, under its id, take
        its name, and a rectification's words name it (an operator reads which component
        recovered, not a number)."""
        placeholder = unnamed_entity(iid)
        self.store.name_entity_events(rid, placeholder, name,
                                      {rectified(placeholder): rectified(name)})

    def _rectification(self, robot: _Robot, s: C_Event_Extension, now: float) -> None:
        rid = robot.resource_id
        ent = s.A_entity_sourceID
        e = robot.entities.get(int(ent.A_instanceId)) if int(ent.A_resourceId) == rid else None
        name = self._entity_name(robot, e, int(ent.A_instanceId))
        t = seconds_of(s.A_timeOfDataGeneration)
        dedup = self._identity(robot, s.A_eventId, f"rectification|{_stamp(t)}|{name}", t, now)
        self.store.add_event(rid, self.clocks.time_of(robot.name, t, now), "rectification",
                             dedup=dedup, entity=name,
                             text=rectified(name),
                             details={"event_id": s.A_eventId[:40], **self._robot_time(
                                 robot, t)})

    def _failure(self, robot: _Robot, s: C_Failure_Event, ext: C_Event_Extension | None = None,
                 now: float = 0.0) -> None:
        rid = robot.resource_id
        ent = s.A_monitoredEntity_sourceID
        e = robot.entities.get(int(ent.A_instanceId)) if int(ent.A_resourceId) == rid else None
        if e is not None:
            e.cause = self._text(s.A_causeDescription, "cause description")
            self.store.put_entity(rid, int(ent.A_instanceId), cause=e.cause,
                                  actions=self._text(s.A_operatorActionDescription,
                                                     "operator action"))
        self._store_event(robot, s, ext, self._failure_row(robot, s, ext, now))

    def _store_event(self, robot: _Robot, s: C_Threshold_Exceedence_Event | C_Failure_Event,
                     ext: C_Event_Extension | None, row: _EventRow) -> None:
        """Store a failure or exceedance heard live; one stored without its identity is
        remembered, so that the identity still finds its row if it comes late."""
        if ext is None:
            self._unnamed[_key(s.A_sourceID)] = _Unnamed(s, row.dedup)
            while len(self._unnamed) > MAX_UNNAMED:
                self._unnamed.popitem(last=False)
            with self._time_keys_lock:
                self._time_keys.setdefault((robot.resource_id, row.dedup),
                                           (_key(s.A_sourceID),
                                            seconds_of(s.A_eventOccurrenceDate)))
                while len(self._time_keys) > MAX_UNNAMED:
                    self._time_keys.popitem(last=False)
        self.store.add_event(robot.resource_id, row.time, row.kind, dedup=row.dedup,
                             entity=row.entity, characteristic=row.characteristic,
                             text=row.text, details=row.details)

    def _name_late(self, robot: _Robot, unnamed: _Unnamed, ext: C_Event_Extension,
                   now: float) -> None:
        """The identity of an event already stored under its time key came: the row is
        re-keyed to the identity (and its number counts as received), or, if the robot's
        log supplied the event under its identity meanwhile, the two rows become one."""
        s = unnamed.sample
        row = self._failure_row(robot, s, ext, now) if isinstance(s, C_Failure_Event) \
            else self._exceedance_row(robot, s, ext, now)
        with self._time_keys_lock:
            owner = self._time_keys.get((robot.resource_id, unnamed.dedup))
            if owner is not None and owner[0] == _key(s.A_sourceID):
                del self._time_keys[(robot.resource_id, unnamed.dedup)]  # the key is free
        if owner is None or owner[0] != _key(s.A_sourceID):
            # The row under that time key is another event's of the same millisecond.
            self._store_event(robot, s, ext, row)
            return
        self.store.name_event(robot.resource_id, unnamed.dedup, row.time, row.kind,
                              dedup=row.dedup, entity=row.entity,
                              characteristic=row.characteristic, text=row.text,
                              details=row.details)

    def _failure_row(self, robot: _Robot, s: C_Failure_Event, ext: C_Event_Extension | None,
                     now: float) -> _EventRow:
        rid = robot.resource_id
        ent = s.A_monitoredEntity_sourceID
        e = robot.entities.get(int(ent.A_instanceId)) if int(ent.A_resourceId) == rid else None
        name = self._entity_name(robot, e, int(ent.A_instanceId))
        t = seconds_of(s.A_eventOccurrenceDate)
        description = self._text(s.A_failureDescription, "failure description")
        cause = self._text(s.A_causeDescription, "cause description")
        action = self._text(s.A_operatorActionDescription, "operator action")
        dedup = self._identity(robot, ext.A_eventId if ext is not None else None,
                               f"failure|{_stamp(t)}|{name}", t, now)
        return _EventRow(
            self.clocks.time_of(robot.name, t, now), "failure", dedup, name, "",
            description + (f": {cause}" if cause else ""),
            {"standard_fault_code": float(s.A_standardFaultCode)
             if math.isfinite(s.A_standardFaultCode) else None,
             "proprietary_fault_code": s.A_proprietaryFaultCode[:200],
             "consequence": s.A_operationalConsequenceDescription[:500],
             "operator_action": action[:500],
             "maintenance_action": s.A_maintenanceActionDescription[:500],
             "complementary": s.A_complementaryInformation[:MAX_STRING],
             "documentation_uri": s.A_eventDocumentationURI[:500],
             "event_id": ext.A_eventId[:40] if ext is not None else "",
             **self._robot_time(robot, t)})

    def _robot_time(self, robot: _Robot, t: float) -> dict[str, float]:
        """The robot's own time of an event placed at the station's time (clock skew)."""
        return {"robot_time": t} if self.clocks.skewed(robot.name) else {}

    def _extension_overdue(self, arrived: float, now: float) -> bool:
        """Whether the extension of what arrived at ``arrived`` can no longer be expected:
        the extension reader had nothing more queued ``EXT_WAIT`` after it arrived, or
        ``EXT_WAIT_MAX`` passed. A burst carries about three extensions per event sample
        and the reader takes ``TAKE`` per poll, so extensions lag several polls behind
        their events: an event stored without its identity meanwhile is keyed by its time
        (two in one millisecond collide), its number looks missing, and the copy the
        robot's log then supplies is keyed by the identity: stored twice."""
        return self._extensions_drained - arrived >= EXT_WAIT \
            or now - arrived >= EXT_WAIT_MAX

    def _resolve_waiting(self, now: float) -> None:
        waiting: list[tuple[float, C_Threshold_Exceedence_Event | C_Failure_Event]] = []
        excess = len(self._waiting) - MAX_WAITING
        for i, (arrived, s) in enumerate(self._waiting):
            ext = self._ext.pop(_key(s.A_sourceID), None)
            if ext is None and i >= excess and not self._extension_overdue(arrived, now):
                waiting.append((arrived, s))
                continue
            robot = self._robot(int(s.A_sourceID.A_resourceId))
            if isinstance(s, C_Failure_Event):
                self._failure(robot, s, ext, now)
            else:
                self._exceedance(robot, s, ext, now)
        self._waiting = waiting
        self._resolve_inferred(now)

    def _resolve_inferred(self, now: float) -> None:
        """Store inferred rectifications of robots that turned out not to name their
        events; drop those of robots that do (they announce every rectification)."""
        keep: list[_InferredRectification] = []
        excess = len(self._inferred) - MAX_WAITING
        for i, r in enumerate(self._inferred):
            robot = self._robots.get(r.resource_id)
            if robot is None or robot.sends_ids:
                continue
            if i >= excess and not self._extension_overdue(r.arrived, now):
                keep.append(r)
                continue
            self.store.add_event(r.resource_id, r.time, "rectification",
                                 dedup=f"rectification|{_stamp(r.time)}|{r.entity}",
                                 entity=r.entity,
                                 text=rectified(r.entity))
        self._inferred = keep

    def _check_sequences(self, now: float) -> None:
        """Tell the operator about events a robot published that never arrived, and fetch
        them from its log (once per hole; what the log lacks too is reported lost)."""
        for robot in self._robots.values():
            if robot.gap_fetch or not robot.sends_ids:
                continue
            with self._sequence_lock:
                gaps = robot.sequences.gaps(now)
            if not gaps:
                continue
            missing = sum(g.count for g in gaps)
            fetch = self.backfill > 0 and robot.robot_id
            self.store.report_problem(
                f"missing events {robot.name}",
                f"{robot.name}: {missing} events not received (numbers "
                + ", ".join(f"{g.first}-{g.last}" if g.count > 1 else str(g.first)
                            for g in gaps[:5])
                + ("); fetching them from the robot's log" if fetch else
                   "); automatic backfill is off"))
            if not fetch:
                with self._sequence_lock:
                    for g in gaps:
                        robot.sequences.give_up(g)
                continue
            robot.gap_fetch = True
            try:
                self._backfills.jobs.put_nowait(self._gap_job(robot, gaps))
            except queue.Full:
                robot.gap_fetch = False  # try again on a later poll

    def _gap_job(self, robot: _Robot, gaps: list[Gap]) -> Callable[[], None]:
        def job() -> None:
            try:
                self._backfill(robot, min(g.after for g in gaps) - 1.0)
                with self._sequence_lock:
                    still = [g for g in robot.sequences.gaps(float("inf"))
                             if any(g.first <= x.last and x.first <= g.last for x in gaps)]
                    for g in still:
                        robot.sequences.give_up(g)
                self.store.clear_problem(f"missing events {robot.name}")
                if still:
                    self.stats.events_lost += sum(g.count for g in still)
                    self.store.report_problem(
                        f"lost events {robot.name}",
                        f"{robot.name}: {sum(g.count for g in still)} events were neither "
                        "received nor found in the robot's log")
            finally:
                robot.gap_fetch = False
        return job

    def _exceedance(self, robot: _Robot, s: C_Threshold_Exceedence_Event,
                    ext: C_Event_Extension | None, now: float = 0.0) -> None:
        self._store_event(robot, s, ext, self._exceedance_row(robot, s, ext, now))

    def _exceedance_row(self, robot: _Robot, s: C_Threshold_Exceedence_Event,
                        ext: C_Event_Extension | None, now: float) -> _EventRow:
        rid = robot.resource_id
        concerned = s.A_concernedCharacteristic_sourceID
        cid = int(concerned.A_instanceId)
        c = robot.chars.get(cid) if int(concerned.A_resourceId) == rid else None
        owner = robot.entities.get(c.entity) if c is not None and c.entity is not None else None
        t = seconds_of(s.A_eventOccurrenceDate)
        state_change = ext is not None and ext.A_kind == T_EventKind.L_EventKind_STATE_CHANGE
        kind = "state_change" if state_change else "exceedance"
        value = float(s.A_measuredValue)
        cname = c.name if c is not None and c.name else f"#{cid}"
        text = f"{cname} = " + (f"{value:.4g}" if math.isfinite(value) else "n/a")
        details: dict[str, Any] = {"characteristic_id": cid,
                                   "value": value if math.isfinite(value) else None}
        if ext is not None:
            details.update(code=int(ext.A_code), code_name=ext.A_codeName[:100],
                           from_states=_items(ext.A_fromStates)[:16],
                           to_states=_items(ext.A_toStates)[:16])
            if ext.A_message:
                text += f": {self._text(ext.A_message, 'event message', 500)}"
            if state_change:
                text += f" (state {', '.join(_items(ext.A_fromStates)[:4])} -> " \
                        f"{', '.join(_items(ext.A_toStates)[:4])})"
        if c is not None and c.observer:
            dedup = f"{kind}|{_stamp(t)}|{c.observer}|{_primary(c.resource)}"
        else:
            dedup = f"{kind}|{_stamp(t)}|#{cid}"
        dedup = self._identity(robot, ext.A_eventId if ext is not None else None, dedup, t, now)
        if ext is not None and ext.A_eventId:
            details["event_id"] = ext.A_eventId[:40]
        details.update(self._robot_time(robot, t))
        return _EventRow(self.clocks.time_of(robot.name, t, now), kind, dedup,
                         owner.name if owner is not None else "", cname, text, details)

    # ---- backfill and operations --------------------------------------------------------

    def _start_backfills(self) -> None:
        """Queue the backfill of every newly named robot, twice: the robot's recorder
        commits what it logged during the last ``commit_interval`` only after it answered
        the first request (the repeat finds those rows; the store drops duplicates)."""
        if self.backfill <= 0:
            return
        now = self.clock()
        for robot in self._robots.values():
            if not robot.robot_id:
                continue
            if robot.backfill_since is None:
                since = now - self.backfill
                if robot.last_heard_before is not None:
                    since = max(since, robot.last_heard_before - 5.0)
                robot.backfill_since = since
                robot.backfill_due = [now, now + BACKFILL_REPEAT]
            while robot.backfill_due and robot.backfill_due[0] <= now:
                if self._backfills.jobs.full():
                    # try again on a later poll; and no other robot either: a fleet new to
                    # the station (1,000 robots, two jobs each) filled the lane for
                    # minutes, and trying each robot at every poll was a tenth of the
                    # follower's work at 500 robots
                    return
                try:
                    self._backfills.jobs.put_nowait(
                        self._backfill_job(robot, robot.backfill_since))
                except queue.Full:
                    return
                robot.backfill_due.pop(0)

    def _backfill_job(self, robot: _Robot, since: float) -> Callable[[], None]:
        return lambda: self._backfill(robot, since)

    def _backfill(self, robot: _Robot, since: float) -> None:
        added = 0

        def take(entries: Sequence[LogEntry]) -> None:
            nonlocal added
            added += self.take_logged(robot.resource_id, entries)

        status, _, _, _ = self._page_log(self._backfills, robot.robot_id, since=since,
                                         until=None, entity=None, characteristic=None,
                                         kinds=BACKFILL_KINDS, max_rows=self.max_log_rows,
                                         on_page=take)
        self.stats.backfilled += added
        if status not in ("done", "truncated"):
            self.store.report_problem("backfill", f"{robot.name}: missed events not fetched: "
                                                  f"{status}")
        self.store.flush(force=True)

    def take_logged(self, resource_id: int, entries: Iterable[LogEntry]) -> int:
        """Store what a backfill fetched from robot ``resource_id``'s log (exceedances,
        failures, announced changes of state) as events; returns how many events were
        offered to the store (one the store already holds under the same key is not added
        again)."""
        robot = self._robot(resource_id)
        return sum(self._log_event(robot, entry) for entry in entries)

    def _log_event(self, robot: _Robot, entry: LogEntry) -> int:
        """Store one backfilled log entry as an event; returns how many events were queued."""
        rid = robot.resource_id
        payload = entry.payload if isinstance(entry.payload, dict) else {}
        t = float(entry.time)
        if entry.kind == "exceedance":
            entity = str(entry.entity or "")
            observer = str(entry.characteristic or "")
            message = str(payload.get("message") or payload.get("code_name") or "")
            owner = self._owner_of(robot, observer, entity)
            time_key = f"exceedance|{_stamp(t)}|{observer}|{entity}"
            dedup = self._identity(robot, payload.get("event_id"), time_key, t,
                                   self.clock(), live=False)
            self._add_logged(robot, time_key, t, "exceedance", dedup=dedup,
                             entity=owner or entity, characteristic=f"{observer} {entity}",
                             text=f"{observer} {entity}: {message}".strip(),
                             details={"log_id": entry.id, "code": entry.code,
                                      "values": payload.get("values"),
                                      "event_id": str(payload.get("event_id") or "")[:40]})
            return 1
        if entry.kind == "failure":
            components = [str(c)[:200] for c in payload.get("components") or []][:100]
            category = payload.get("category")
            explanation = str(payload.get("explanation") or "")[:MAX_STRING]
            n = 0
            named = payload.get("events")
            if isinstance(named, list):
                n = self._logged_diagnosis_events(robot, named, t, explanation, entry.id,
                                                  payload.get("snapshot"))
            # Named events stand for each failure and rectification exactly.
            for comp in [] if isinstance(named, list) else components:
                if category == "rectification":
                    self.store.add_event(rid, t, "rectification",
                                         dedup=f"rectification|{_stamp(t)}|{comp}",
                                         entity=comp, origin="log",
                                         text=rectified(comp),
                                         details={"log_id": entry.id})
                else:
                    self.store.add_event(rid, t, "failure", dedup=f"failure|{_stamp(t)}|{comp}",
                                         entity=comp, origin="log",
                                         text=f"{comp} diagnosed faulty"
                                              + (f": {explanation}" if explanation else ""),
                                         details={"log_id": entry.id,
                                                  "snapshot": payload.get("snapshot")})
                n += 1
            now_components = frozenset() if category == "rectification" else frozenset(
                components)
            text = explain(robot.name, sorted(now_components), {}, {})
            if explanation and now_components:
                text += f" Explanation: {explanation}"
            self.store.add_event(rid, t, "diagnosis",
                                 dedup=_diagnosis_key(t, now_components),
                                 text=text, origin="log",
                                 details={"components": sorted(now_components)})
            return n + 1
        if entry.kind == "observation":
            return self._logged_state_change(robot, entry, payload, t)
        return 0

    def _logged_state_change(self, robot: _Robot, entry: LogEntry, payload: dict[str, Any],
                             t: float) -> int:
        """A logged observation row that the robot announced as a change of state (it
        carries the event's identity); other observation rows (recoveries, changes of
        code) are no events and are not stored."""
        event_id = payload.get("event_id")
        if not isinstance(event_id, str) or EventId.parse(event_id) is None:
            return 0
        entity = str(entry.entity or "")
        observer = str(entry.characteristic or "")
        dedup = self._identity(robot, event_id, f"state_change|{_stamp(t)}|{observer}|{entity}",
                               t, self.clock(), live=False)
        names = payload.get("state_names")
        states = [str(x)[:100] for x in names[:4]] if isinstance(names, list) else []
        message = str(payload.get("message") or payload.get("code_name") or "")[:500]
        text = f"{observer} {entity}: {message}".strip()
        if states:
            text += f" (state -> {', '.join(states)})"
        # Heard live without its extension it was stored as an exceedance.
        self._add_logged(robot, f"exceedance|{_stamp(t)}|{observer}|{entity}", t,
                         "state_change", dedup=dedup,
                         entity=self._owner_of(robot, observer, entity) or entity,
                         characteristic=f"{observer} {entity}", text=text,
                         details={"log_id": entry.id, "code": entry.code,
                                  "values": payload.get("values"), "to_states": states,
                                  "event_id": event_id[:40]})
        return 1

    def _add_logged(self, robot: _Robot, time_key: str, t: float, kind: str, *, dedup: str,
                    entity: str, characteristic: str, text: str,
                    details: dict[str, Any]) -> None:
        """Store a logged event. If its live copy was stored under ``time_key`` (its
        identity never came, or not yet), that row takes the identity instead of a second
        copy being added."""
        # The row under the time key is this event's only if its owner has the same time
        # (events of one millisecond share the key).
        with self._time_keys_lock:
            owner = self._time_keys.get((robot.resource_id, time_key))
            if owner is None and (placeholder := self._placeholder_key(robot, time_key)):
                owner = self._time_keys.get((robot.resource_id, placeholder))
                time_key = placeholder if owner is not None else time_key
            mine = owner is not None and abs(owner[1] - t) < 1e-6 and dedup.startswith("id:")
            if mine:
                del self._time_keys[(robot.resource_id, time_key)]  # the key is free
        if mine:
            self.store.name_event(robot.resource_id, time_key, t, kind, dedup=dedup,
                                  entity=entity, characteristic=characteristic, text=text,
                                  origin="log", details=details, rewrite=False)
            return
        self.store.add_event(robot.resource_id, t, kind, dedup=dedup, entity=entity,
                             characteristic=characteristic, text=text, origin="log",
                             details=details)

    @staticmethod
    def _placeholder_key(robot: _Robot, time_key: str) -> str | None:
        """The time key a live event of the entity ``time_key`` ends with was stored under
        while that entity had no description yet (its id, ``#<id>``; renaming the entity
        renames its events, never their keys), or ``None`` for no described entity."""
        head, _, name = time_key.rpartition("|")
        for iid, entity in list(robot.entities.items()):  # the reading thread may add
            if entity.name == name:
                return f"{head}|{unnamed_entity(iid)}"
        return None

    def _logged_diagnosis_events(self, robot: _Robot, named: list[Any], t: float,
                                 explanation: str, log_id: int, snapshot: Any) -> int:
        """Failures and rectifications a logged diagnosis row names with their identities."""
        n = 0
        for item in named[:100]:
            if not isinstance(item, dict) or item.get("kind") not in ("failure",
                                                                      "rectification"):
                continue
            comp = str(item.get("entity") or "")[:200]
            kind = str(item["kind"])
            time_key = f"{kind}|{_stamp(t)}|{comp}"
            dedup = self._identity(robot, item.get("id"), time_key, t, self.clock(),
                                   live=False)
            text = rectified(comp) if kind == "rectification" else \
                f"{comp} diagnosed faulty" + (f": {explanation}" if explanation else "")
            details: dict[str, Any] = {"log_id": log_id, "event_id": str(item.get("id"))[:40]}
            if kind == "failure":
                details["snapshot"] = snapshot
            self._add_logged(robot, time_key, t, kind, dedup=dedup, entity=comp,
                             characteristic="", text=text, details=details)
            n += 1
        return n

    def _owner_of(self, robot: _Robot, observer: str, entity: str) -> str:
        for c in list(robot.chars.values()):  # the reading thread may add to it
            if c.observer == observer and _primary(c.resource) == entity and c.entity:
                owner = robot.entities.get(c.entity)
                if owner is not None:
                    return owner.name
        return ""

    def _page_log(self, lane: _Lane, robot_id: str, *, since: float | None, until: float | None,
                  entity: str | None, characteristic: str | None, kinds: Sequence[str],
                  max_rows: int, on_page: Callable[[Sequence[LogEntry]], None],
                  on_progress: Callable[[int, int, float], None] | None = None,
                  ) -> tuple[str, int, int, str]:
        """Fetch a robot's log in time order, ``log_page`` entries per log request
        (:meth:`_fetch_log`), each page starting at the time of the last entry received;
        returns (status, rows, pages, message). Bounded: at most ``max_rows`` rows."""
        rows = pages = 0
        cursor: tuple[float, int] | None = None
        same = 0  # entries already taken at the cursor's instant: the next page repeats them
        first: float | None = since
        span_end = until if until is not None else self.clock()
        while rows < max_rows:
            if self._stop.is_set():
                return "error", rows, pages, "station stopping"
            if same > 10 * self.log_page:
                return "error", rows, pages, (f"more than {same} entries at one instant "
                                       f"({cursor[0] if cursor else since}); narrow the request")
            want = min(self.log_page, max_rows - rows)
            ask = want + same
            answer = self._fetch_log(lane, robot_id, entity=entity, characteristic=characteristic,
                                     since=cursor[0] if cursor else since, until=until,
                                     kinds=kinds, max_entries=ask)
            pages += 1
            if answer.status != "ok":
                kind = "timeout" if answer.status.startswith("timeout") else "error"
                return kind, rows, pages, answer.status
            entries: list[LogEntry] = []
            for item in answer.entries:
                try:
                    entry = LogEntry(int(item["id"]), float(item["time"]), str(item["kind"]),
                                     item.get("entity"), item.get("characteristic"),
                                     item.get("code"), item.get("payload") or {})
                except (KeyError, TypeError, ValueError):
                    self.store.report_problem("log reply", f"{robot_id}: malformed entry "
                                                           "ignored")
                    continue
                if cursor is not None and (entry.time, entry.id) <= cursor:
                    continue
                entries.append(entry)
            entries = entries[: max_rows - rows]
            if entries:
                on_page(entries)
                rows += len(entries)
                if first is None:
                    first = entries[0].time
                last = entries[-1]
                same = (same if cursor is not None and last.time == cursor[0] else 0) + sum(
                    1 for e in entries if e.time == last.time)
                cursor = (last.time, last.id)
            end = len(answer.entries) < ask
            if on_progress is not None:
                covered = 1.0
                if not end and first is not None and cursor is not None and span_end > first:
                    covered = (cursor[0] - first) / (span_end - first)
                on_progress(rows, pages, covered)
            if end:
                return "done", rows, pages, ""
            if not entries:
                return "error", rows, pages, "the robot repeated entries it had sent already"
        return "truncated", rows, pages, f"stopped at {max_rows} rows; narrow the time range"

    def _fetch_log(self, lane: _Lane, robot_id: str, *, entity: str | None,
                   characteristic: str | None, since: float | None, until: float | None,
                   kinds: Iterable[str], max_entries: int) -> LogAnswer:
        """The one place this station sends a log request (signing is added here)."""
        client = lane.client
        if client is None:
            return LogAnswer("error: station not connected", [], 0, False)
        with lane.lock:
            answer = client.request(robot_id, entity=entity, characteristic=characteristic,
                                    since=since, until=until, kinds=kinds,
                                    max_entries=max_entries, timeout=self.log_timeout,
                                    robot_key=self._robot_key(robot_id))
        late = client.late_forged()
        late[robot_id] = late.get(robot_id, 0) + answer.forged
        self._count_forged_replies(late)
        return answer

    def _count_forged_replies(self, forged: dict[str, int]) -> None:
        for robot_id, n in forged.items():
            if n <= 0:
                continue
            self.gate.stats.forged += n
            self.store.report_problem(f"forged data {robot_id}",
                                      f"{robot_id}: {n} log reply chunks without "
                                      "the robot's signature were dropped")

    def _drop_foreign_replies(self) -> None:
        """Log replies keep all history: between our own requests, replies to other
        stations would pile up in the reader, so they are taken and dropped."""
        for lane in (self._requests, self._backfills):
            client = lane.client
            if client is None or not lane.lock.acquire(blocking=False):
                continue
            try:
                self._count_forged_replies(client.take_late(256))
            except Exception as exc:
                self.store.report_problem("dds BlackBox_Log_Reply", f"cannot read: {exc}")
            finally:
                lane.lock.release()

    def request_logs(self, robot: RobotRef, *, entity: str | None = None,
                     characteristic: str | None = None, since: float | None = None,
                     until: float | None = None, kinds: Iterable[str] = (),
                     requested_by: str = "", max_rows: int | None = None) -> int:
        """Ask ``robot`` for its recorded log (of one entity, or all with ``entity=None``)
        between ``since`` and ``until``; returns the request id at once. Progress, status
        and rows: ``store.log_request(id)``, ``store.log_entries(id, ...)``,
        ``store.export_log(id, fmt, out)``. At most ``max_rows`` (default and cap 200,000)
        rows are kept (status ``truncated`` beyond).

        Raises :class:`UnknownRobot`, ``ValueError`` (bad range or kinds),
        :class:`StationBusy` (request queue full) or ``StationStoreError`` (disk full)."""
        rid = self.store.resource_of(robot)
        robot_id = self.store.robot_id_of(rid)
        if robot_id.startswith("#"):
            raise UnknownRobot(f"robot {robot!r} has not named itself; cannot address it")
        chosen = [str(k) for k in kinds]
        bad = [k for k in chosen if k not in KINDS]
        if bad:
            raise ValueError(f"unknown log kind(s) {', '.join(bad)}; known: {', '.join(KINDS)}")
        for label, value in (("since", since), ("until", until)):
            if value is not None and (not math.isfinite(value) or value < 0):
                raise ValueError(f"{label} must be a time in seconds since the epoch")
        if since is not None and until is not None and until < since:
            raise ValueError("until is before since")
        if since is not None and (until or self.clock()) - since > MAX_LOG_RANGE_DAYS * 86400:
            raise ValueError(f"range longer than {MAX_LOG_RANGE_DAYS} days")
        limit = min(max_rows or self.max_log_rows, self.max_log_rows)
        if self._requests.jobs.full():
            raise StationBusy("too many log requests and tests waiting; try again shortly")
        request = self.store.create_log_request(
            rid, robot_id, entity=entity or None, characteristic=characteristic or None,
            since=since, until=until, kinds=chosen, requested_by=requested_by)
        self.store.add_event(rid, self.clock(), "log_request", dedup=f"log_request|{request}",
                             entity=entity or "", origin="station",
                             text=f"{requested_by or 'someone'} requested the log of "
                                  f"{entity or 'every entity'}",
                             details={"request": request, "since": since, "until": until,
                                      "kinds": chosen})

        def job() -> None:
            self._run_log_request(request, rid, robot_id, entity or None,
                                  characteristic or None, since, until, chosen, limit)
        try:
            self._requests.jobs.put_nowait(job)
        except queue.Full:
            self.store.update_log_request(request, rid, status="error", rows=0, pages=0,
                                          progress=0, message="station busy",
                                          finished=self.clock())
            self.store.flush(force=True)
            raise StationBusy("too many log requests and tests waiting; try again "
                              "shortly") from None
        self.store.flush(force=True)
        return request

    def _run_log_request(self, request: int, rid: int, robot_id: str, entity: str | None,
                         characteristic: str | None, since: float | None, until: float | None,
                         kinds: Sequence[str], max_rows: int) -> None:
        self.store.update_log_request(request, rid, status="running", rows=0, pages=0,
                                      progress=0.0)
        self.store.flush(force=True)
        seq = 0

        def page(entries: Sequence[LogEntry]) -> None:
            nonlocal seq
            self.store.add_log_rows(request, seq, entries)
            seq += len(entries)

        def progress(rows: int, pages: int, covered: float) -> None:
            self.store.update_log_request(request, rid, status="running", rows=rows,
                                          pages=pages, progress=covered)
            self.store.flush(force=True)

        try:
            status, rows, pages, message = self._page_log(self._requests,
                robot_id, since=since, until=until, entity=entity,
                characteristic=characteristic, kinds=kinds, max_rows=max_rows,
                on_page=page, on_progress=progress)
        except Exception as exc:  # a failed request is a result, not a crash
            log.exception("station: log request %d failed", request)
            status, rows, pages, message = "error", seq, 0, str(exc)
        info = self.store.log_request(request)
        self.store.update_log_request(request, rid, status=status, rows=rows, pages=pages,
                                      progress=1.0 if status == "done" else
                                      (info.progress if info else 0.0),
                                      message=message, finished=self.clock())
        if not self.store.flush(force=True):
            self.store.report_problem("logs", f"log request {request}: rows are kept in "
                                              "memory until the database can be written")

    def run_ibit(self, robot: RobotRef, entity: str = "", requested_by: str = "") -> int:
        """Ask ``robot`` to run its built-in test on ``entity`` ("" = the whole robot);
        returns the run id at once; the result is ``store.ibit_run(id)`` and an ``ibit``
        event. Raises :class:`UnknownRobot`, :class:`StationBusy`, ``StationStoreError``."""
        rid = self.store.resource_of(robot)
        robot_id = self.store.robot_id_of(rid)
        if robot_id.startswith("#"):
            raise UnknownRobot(f"robot {robot!r} has not named itself; cannot address it")
        if entity and self.store.entity_by_name(rid, entity) is None:
            raise UnknownRobot(f"robot {robot_id} has no entity {entity!r}")
        if self._requests.jobs.full():
            raise StationBusy("too many log requests and tests waiting; try again shortly")
        run = self.store.create_ibit_run(rid, robot_id, entity, requested_by)

        def job() -> None:
            self._run_ibit(run, rid, robot_id, entity, requested_by)
        try:
            self._requests.jobs.put_nowait(job)
        except queue.Full:
            self.store.finish_ibit_run(run, rid, status="error", health=None, observations=0,
                                       failed=0, report=["station busy"])
            self.store.flush(force=True)
            raise StationBusy("too many requests waiting; try again shortly") from None
        return run

    def _run_ibit(self, run: int, rid: int, robot_id: str, entity: str, user: str) -> None:
        from blackbox.transport.ibit import request_ibit

        bus = self.bus
        result = None
        if bus is not None:
            try:
                def forged(_: Any) -> None:
                    self.gate.stats.forged += 1
                    self.store.report_problem(f"forged data {robot_id}",
                                              f"{robot_id}: a built-in test result without "
                                              "the robot's signature was ignored")
                result = request_ibit(bus, robot_id, entity=entity, timeout=self.ibit_timeout,
                                      signer=self.signer, robot_key=self._robot_key(robot_id),
                                      on_forged=forged)
            except Exception as exc:
                self.store.report_problem("ibit", f"{robot_id}: {exc}")
        now = self.clock()
        if result is None:
            self.store.finish_ibit_run(run, rid, status="timeout", health=None, observations=0,
                                       failed=0, report=["no answer from the robot"])
            text = f"built-in test of {entity or robot_id}: no answer"
            health = None
        else:
            raw = int(result.A_healthStatus.value)
            health = STATUSES[raw] if 0 <= raw < len(STATUSES) else "UNKNOWN"
            self.store.finish_ibit_run(run, rid, status="done", health=health,
                                       observations=int(result.A_observations),
                                       failed=int(result.A_failed),
                                       report=[str(r) for r in _items(result.A_report)[:1000]])
            text = (f"built-in test of {entity or robot_id}: {health}, "
                    f"{int(result.A_failed)} of {int(result.A_observations)} checks failed")
        self.store.add_event(rid, now, "ibit", dedup=f"ibit|{run}", entity=entity,
                             origin="station", text=text,
                             details={"run": run, "requested_by": user, "health": health})
        self.store.flush(force=True)

    def _work(self, lane: _Lane) -> None:
        while not self._stop.is_set():
            job = lane.jobs.get()
            if job is None:
                return
            try:
                job()
            except StationStoreError as exc:
                self.store.report_problem("store", str(exc))
            except Exception as exc:
                log.exception("station: request failed")
                self.store.report_problem("requests", f"request failed: {exc}")

    # ---- for blackbox listen ------------------------------------------------------------

    def snapshot(self, events: int = 50) -> dict[str, Any]:
        """The whole state as plain data (what ``blackbox listen --json`` prints)."""
        out: dict[str, Any] = {}
        for summary in self.store.fleet():
            rid = summary.resource_id
            ents = self.store.entities(rid)
            chars = self.store.characteristics(rid)
            page = self.store.events(rid, limit=events)
            out[summary.name] = {
                "robot_id": summary.robot_id, "resource_id": rid, "status": summary.status,
                "stale": summary.stale, "online": summary.online,
                "diagnosis": list(summary.diagnosis),
                "entities": {e.name: {"health": e.reported_status, "online": e.online,
                                      "kind": e.kind, "bit": e.bit_in_progress,
                                      "failures": e.failures} for e in ents},
                "characteristics": {c.name: c.value for c in chars},
                "events": [{"time": e.time, "kind": e.kind, "entity": e.entity,
                            "text": e.text, "origin": e.origin}
                           for e in reversed(page.events)],
            }
        trust = self.gate.stats
        return {"robots": out, "received": self.stats.received,
                "rejected": self.stats.rejected,
                "trust": {"verified": trust.verified, "forged": trust.forged,
                          "unsigned": trust.unsigned, "replayed": trust.replayed,
                          "superseded": trust.superseded,
                          "unauthenticated": trust.unauthenticated,
                          "second_writers": trust.second_writers},
                "problems": [f"{p.source}: {p.message}" for p in self.store.problems()]}


def robot_ref(text: str) -> RobotRef:
    """A :data:`RobotRef` from user input (digits or ``#digits`` = resource id)."""
    return int(text) if text.isdigit() else robot_resource(text) if text.startswith("#") \
        else text
