"""The health bus over Zenoh: robots reach a station across networks through routers.

DDS discovery is all-to-all and its multicast does not cross a WAN; Zenoh routers do. This
bus offers the surface the DDS :class:`~blackbox.transport.participant.Bus` offers to the
sink, the log and IBIT services and the station follower (``writer``, ``reader``,
``waiter``, ``close``), so those need not know which bus carries them. Samples are the same
Cyclone IDL types, serialised with their own CDR, under the key expression
``<partition>/<origin>/<topic>`` (``blackbox/<robot_id>/C_Failure_Event`` by default).

What DDS's durability gives the station, Zenoh's advanced publisher and subscriber give here:
every published topic keeps its last :data:`CACHED_SAMPLES` samples on the robot; a station
that joins late asks for them (the TransientLocal of DDS), and a station that missed samples
(a robot that published before the station heard of it, or while a router was down)
notices the gap in the publisher's sequence numbers (heartbeats) and fetches exactly
those, in order, when the link returns. The station does not query each robot's history
as it appears (``detect_late_publishers``): with 7,500 or more publishers (500 robots of
15 topics) a subscriber doing so delivered nothing at all (docs/benchmarks.md). A
publisher first met through a live sample would lose its earlier samples to the advanced
subscriber's duplicate check; :mod:`~blackbox.transport.zenoh_contact` fetches them.
Beyond the cache the station's hole fetch by event identity reads the rest from the
recorder's log. Requests and replies are
volatile, as on DDS: a lost request is retried by its caller.
"""

from __future__ import annotations

import contextlib
import re
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import zenoh
import zenoh.ext as zext

from blackbox.errors import BlackBoxError
from blackbox.transport.cdr_decoder import decoder_for
from blackbox.transport.cdr_encoder import Encoder, encoder_for
from blackbox.transport.topics import ALL_TOPICS
from blackbox.transport.zenoh_contact import FirstContact

CACHED_SAMPLES = 4096
"""Samples each published topic keeps for late or reconnecting stations (per robot)."""
HEARTBEAT_SECONDS = 0.5
"""How often a publisher tells subscribers its last sequence number, so that a station
notices samples it missed even when the robot has nothing new to say."""
CONNECT_WAIT_MS = 10_000
"""How long opening a session waits for a router before it gives up with an error."""
READER_DEPTH = 100_000
"""Samples a reader holds between two takes; beyond it the oldest go (and are counted)."""
CHANNEL_DEPTH = 100_000
"""Samples Zenoh holds for a reader until they are moved to its queue (at every take and
every wait, so a full channel means the reading thread is stuck: Zenoh then holds back
delivery rather than dropping)."""
WAIT_STEP = 0.01
"""Seconds between two looks at the readers while waiting for samples."""
VOLATILE_TOPICS = frozenset({"BlackBox_Log_Request", "BlackBox_Log_Reply",
                             "C_Monitored_Entity_run_IBIT", "BlackBox_IBIT_Request",
                             "BlackBox_IBIT_Result"})
"""Request/reply topics: an old request must not be answered again, nor an old reply taken."""
CDR_HEADER = 4
"""Bytes of the encapsulation header every serialised sample starts with."""
_NOT_IN_KEY = re.compile(r"[^A-Za-z0-9_.\-]")
ENDPOINT = re.compile(r"^(tcp|tls|udp|quic)/[^/\s]+:[0-9]{1,5}$")


class ZenohError(BlackBoxError, RuntimeError):
    """The Zenoh session cannot be opened (bad endpoint, certificate, ...)."""


def first_line(exc: BaseException) -> str:
    """Zenoh's message without the Rust source location it ends with."""
    return str(exc).split(" at /", 1)[0].splitlines()[0] if str(exc) else type(exc).__name__


def key_part(text: str) -> str:
    """``text`` as one chunk of a key expression: wildcards and separators replaced."""
    return _NOT_IN_KEY.sub("_", text) or "_"


@dataclass(frozen=True, slots=True)
class ZenohSettings:
    """Where the session connects (``tcp/host:port`` or ``tls/host:port`` of a router) and,
    for TLS, the CA that signed the router's certificate (and this side's own certificate
    and key when the router asks for one)."""

    endpoints: tuple[str, ...]
    partition: str = "blackbox"
    root_ca: str | None = None
    certificate: str | None = None
    private_key: str | None = None
    router_optional: bool = False
    """A robot's session: it opens at once, router or not, and connects whenever a router
    appears (so the black box runs, records and publishes into its cache meanwhile, and
    delivers in order when the link comes). A station's session (``False``) waits
    :data:`CONNECT_WAIT_MS` for a router and otherwise stops with a clear error."""

    def __post_init__(self) -> None:
        if not self.endpoints:
            raise ValueError("a Zenoh endpoint is required, e.g. tcp/127.0.0.1:7447")
        for endpoint in self.endpoints:
            if not ENDPOINT.match(endpoint):
                raise ValueError(f"not a Zenoh endpoint: {endpoint!r} "
                                 "(expected e.g. tcp/127.0.0.1:7447 or tls/host:7447)")

    def config(self) -> zenoh.Config:
        """A client of the routers: no multicast scouting (nothing is announced on the LAN).
        Opening waits :data:`CONNECT_WAIT_MS` for a router and fails after that (a Zenoh
        client cannot open without one); once open, a lost router is reconnected in the
        background. With :attr:`router_optional` the session is a Zenoh peer instead, the
        one mode that opens without a router: it listens nowhere (so it is reached only
        through the router, like a client, and opens no socket of its own) and keeps
        trying the routers' endpoints in the background for as long as it runs."""
        config = zenoh.Config()
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("connect/endpoints", _json_list(self.endpoints))
        if self.router_optional:
            config.insert_json5("mode", '"peer"')
            config.insert_json5("listen/endpoints", "[]")
            config.insert_json5("scouting/gossip/enabled", "false")
            config.insert_json5("scouting/delay", "0")  # no peers to wait for: open at once
        else:
            config.insert_json5("mode", '"client"')
            config.insert_json5("connect/timeout_ms", str(CONNECT_WAIT_MS))
            config.insert_json5("connect/exit_on_failure", "false")
        apply_tls(config, self.root_ca, self.certificate, self.private_key)
        return config


def apply_tls(config: zenoh.Config, root_ca: str | None, certificate: str | None,
              private_key: str | None) -> None:
    """The TLS files of a session (client or router); both or neither of certificate and
    key."""
    if (certificate is None) != (private_key is None):
        raise ValueError("a TLS certificate needs its private key and the key its certificate")
    if root_ca is not None:
        config.insert_json5("transport/link/tls/root_ca_certificate", _json_str(root_ca))
    if certificate is not None and private_key is not None:
        config.insert_json5("transport/link/tls/listen_certificate", _json_str(certificate))
        config.insert_json5("transport/link/tls/listen_private_key", _json_str(private_key))
        config.insert_json5("transport/link/tls/connect_certificate", _json_str(certificate))
        config.insert_json5("transport/link/tls/connect_private_key", _json_str(private_key))


def _json_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _json_list(items: Iterable[str]) -> str:
    return "[" + ",".join(_json_str(i) for i in items) + "]"


@dataclass(frozen=True, slots=True)
class _Matched:
    """What ``matched_both_ways`` asks of a matched endpoint: whose it is."""

    participant_key: str = "zenoh"


def _encoder(topic: str) -> Encoder | None:
    """The precompiled encoder of the topic's type (``cdr_encoder``: the bytes
    ``serialize()`` gives, about 1 us instead of 27 us for a characteristic value), or
    ``None`` where the type has none and keeps ``serialize()``."""
    datatype: Any = ALL_TOPICS.get(topic)
    if datatype is None:
        return None
    return encoder_for(datatype, datatype.__idl__.default_version == 2)


class ZenohWriter:
    """Writes one topic's samples under this bus's origin, like a DDS DataWriter."""

    def __init__(self, session: zenoh.Session, key: str, topic: str) -> None:
        self.key = key
        self.topic = topic
        self._volatile = topic in VOLATILE_TOPICS
        self._encode = _encoder(topic)
        self._publisher: Any
        if self._volatile:
            self._publisher = session.declare_publisher(key)
        else:
            # BLOCK, as a reliable DDS writer: a full send queue in a burst waits rather
            # than drops (with no route at all, while the router is down, nothing waits)
            self._publisher = zext.declare_advanced_publisher(
                session, key, congestion_control=zenoh.CongestionControl.BLOCK,
                cache=zext.CacheConfig(max_samples=CACHED_SAMPLES),
                sample_miss_detection=zext.MissDetectionConfig(
                    heartbeat=HEARTBEAT_SECONDS, sporadic_heartbeat=None),
                publisher_detection=True)

    def write(self, sample: Any) -> None:
        if self._encode is not None and type(sample) is ALL_TOPICS[self.topic]:
            self._publisher.put(self._encode(sample))
        else:
            self._publisher.put(sample.serialize())

    def unregister_instance(self, sample: Any) -> None:
        """DDS frees an event instance here; Zenoh keeps no instances."""

    def get_matched_subscriptions(self) -> list[int]:
        matching = self._publisher.matching_status.matching if self._volatile else True
        return [0] if matching else []

    def get_matched_subscription_data(self, handle: int) -> _Matched:
        return _Matched()

    def close(self) -> None:
        self._publisher.undeclare()


class ZenohReader:
    """Holds one topic's samples from every origin until :meth:`take`, like a DDS
    DataReader; payloads that are not a sample of the topic are counted and skipped.

    Samples wait in a channel of Zenoh's own (:data:`CHANNEL_DEPTH`) and are moved into
    this reader's queue (:data:`READER_DEPTH`, the oldest dropped and counted beyond it)
    by whoever takes or waits. Why not a callback per sample: each one takes the GIL on
    Zenoh's receive thread, and at a fleet's ten thousand samples a second those threads
    and the station's thread spent their time handing the GIL to each other (measured:
    a callback costs about 10 us more per sample than draining a channel)."""

    def __init__(self, session: zenoh.Session, key: str, topic: str) -> None:
        self.topic = topic
        self.type: Any = ALL_TOPICS[topic]
        self._payloads: deque[bytes] = deque(maxlen=READER_DEPTH)
        self._lock = threading.Lock()
        self.malformed = 0
        self._overflowed = 0
        self._subscriber: Any
        channel: Any = zenoh.handlers.FifoChannel(CHANNEL_DEPTH)
        self._first_contact: FirstContact | None = None
        if topic in VOLATILE_TOPICS:
            self._subscriber = session.declare_subscriber(key, channel)
        else:
            self._subscriber = zext.declare_advanced_subscriber(
                session, key, channel,
                history=zext.HistoryConfig(detect_late_publishers=False),
                recovery=zext.RecoveryConfig(heartbeat=True, periodic_queries=None),
                subscriber_detection=True)
            self._first_contact = FirstContact(session)

    def pull(self) -> int:
        """Move what the channel holds into the queue; how many samples wait there."""
        with self._lock:
            receive = self._subscriber.try_recv
            contact = self._first_contact
            while (sample := receive()) is not None:
                payload = sample.payload.to_bytes()
                if contact is None or contact.passes(sample, payload):
                    self._queue(payload)
            if contact is not None:
                for payload in contact.released():
                    self._queue(payload)
            return len(self._payloads)

    def _queue(self, payload: bytes) -> None:
        if len(self._payloads) == self._payloads.maxlen:
            self._overflowed += 1
        self._payloads.append(payload)

    @property
    def recovered(self) -> int:
        """Samples fetched from publishers' caches that a first live sample would have
        cost (:mod:`~blackbox.transport.zenoh_contact`)."""
        return 0 if self._first_contact is None else self._first_contact.recovered

    @property
    def overflowed(self) -> int:
        """Samples dropped because the queue was full (counted as they come in)."""
        self.pull()
        return self._overflowed

    def take(self, N: int = 1) -> list[Any]:  # the DataReader's own argument name
        self.pull()
        with self._lock:
            payloads = [self._payloads.popleft() for _ in range(min(N, len(self._payloads)))]
        samples = []
        decode = decoder_for(self.type)  # compiled: cyclonedds's sample, about 10x faster
        for payload in payloads:
            if len(payload) < CDR_HEADER:  # Cyclone decodes b"" as an all-default sample
                self.malformed += 1
                continue
            try:
                samples.append(decode(payload))
            except Exception:  # a foreign or truncated payload is not a crash
                self.malformed += 1
        return samples

    def get_matched_publications(self) -> list[int]:
        return [0]

    def get_matched_publication_data(self, handle: int) -> _Matched:
        return _Matched()

    def close(self) -> None:
        self._subscriber.undeclare()


@dataclass
class ZenohWaiter:
    """Waits until some reader of the bus has samples (or the timeout passes), looking
    every :data:`WAIT_STEP` seconds (the readers' channels cannot wake a thread)."""

    readers: list[ZenohReader]

    def wait(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while not any(reader.pull() for reader in self.readers):
            left = deadline - time.monotonic()
            if left <= 0:
                return
            time.sleep(min(WAIT_STEP, left))


@dataclass
class ZenohBus:
    """One Zenoh client session; writers publish under ``origin``, readers hear every
    origin in the partition. A bus made by :meth:`sharing` uses a session that someone
    else opened (many robots of one gateway or of a simulated fleet in one process): it
    closes its own writers and readers, never the session."""

    settings: ZenohSettings
    session: zenoh.Session
    origin: str
    owns_session: bool = True
    readers: list[ZenohReader] = field(default_factory=list)
    writers_: list[ZenohWriter] = field(default_factory=list)

    @classmethod
    def open(cls, settings: ZenohSettings, origin: str | None = None) -> ZenohBus:
        try:
            session = zenoh.open(settings.config())
        except Exception as exc:
            raise ZenohError(f"cannot open a Zenoh session to "
                             f"{', '.join(settings.endpoints)}: {first_line(exc)}") from None
        return cls(settings, session, key_part(origin or f"node-{session.info.zid()}"))

    @classmethod
    def sharing(cls, settings: ZenohSettings, session: zenoh.Session, origin: str) -> ZenohBus:
        """A bus publishing under ``origin`` on an open ``session`` it does not own."""
        return cls(settings, session, key_part(origin), owns_session=False)

    def key(self, origin: str, topic: str) -> str:
        return f"{key_part(self.settings.partition)}/{origin}/{topic}"

    def writer(self, name: str) -> ZenohWriter:
        writer = ZenohWriter(self.session, self.key(self.origin, name), name)
        self.writers_.append(writer)
        return writer

    def reader(self, name: str, qos: Any = None) -> ZenohReader:
        reader = ZenohReader(self.session, self.key("*", name), name)
        self.readers.append(reader)
        return reader

    def waiter(self, readers: Iterable[Any]) -> ZenohWaiter:
        return ZenohWaiter([r for r in readers if isinstance(r, ZenohReader)])

    def malformed(self) -> int:
        return sum(r.malformed for r in self.readers)

    def close(self) -> None:
        endpoints: list[ZenohReader | ZenohWriter] = [*self.readers, *self.writers_]
        for endpoint in endpoints:
            with contextlib.suppress(Exception):  # already gone with the session
                endpoint.close()
        self.readers.clear()
        self.writers_.clear()
        if not self.owns_session:
            return
        session: Any = self.session  # its stub leaves close() untyped
        session.close()


__all__ = ["CACHED_SAMPLES", "ZenohBus", "ZenohError", "ZenohSettings",
           "apply_tls", "key_part"]
