"""One DDS participant per process, on loopback unless told otherwise.

Which Cyclone configuration applies, first match wins: an explicit ``cyclone_config`` (XML
or a ``file://`` URI), the ``CYCLONEDDS_URI`` environment variable (Cyclone's own
convention), else :data:`LOOPBACK_CONFIG`, so that nothing leaves the machine unless
the operator says so. The receiving sockets Cyclone binds to the wildcard address are then
pinned to that configuration's interface (:mod:`blackbox.transport.sockets`), and its
log output is filtered so that a flood of malformed datagrams cannot flood the log
(:mod:`blackbox.transport.cyclone_log`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from cyclonedds.core import (
    DDSException,
    InstanceState,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from blackbox.transport.cyclone_log import limit_malformed_packet_logging
from blackbox.transport.qos import partition, qos_for
from blackbox.transport.sockets import configured_interface, pin_new_sockets, udp_wildcard_sockets
from blackbox.transport.topics import ALL_TOPICS as ALL_TOPICS  # re-exported
from blackbox.transport.topics import TOPIC_OF_TYPE as TOPIC_OF_TYPE

if TYPE_CHECKING:
    from blackbox.transport.zenoh_bus import ZenohSettings

LOOPBACK_CONFIG = (
    '<General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>40</MaxAutoParticipantIndex>"
    '<Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
)
"""Loopback only, unicast discovery: what tests and the default demo use."""




@dataclass(frozen=True, slots=True)
class TransportSettings:
    domain_id: int = 0
    partition: str = "blackbox"
    cyclone_config: str | None = None
    zenoh: ZenohSettings | None = None
    """Carry everything over Zenoh through these routers instead of DDS."""

    def __post_init__(self) -> None:
        if not 0 <= self.domain_id <= 232:
            raise ValueError(f"domain id must be 0..232, got {self.domain_id}")
        if not self.partition:
            raise ValueError("partition must not be empty")


class Waiter(Protocol):
    def wait(self, seconds: float) -> None:
        """Return when some of the readers has samples, or after ``seconds``."""


class HealthBus(Protocol):
    """What the sink, the log and IBIT services and the station follower need of a bus:
    DDS (:class:`Bus`) on one network, Zenoh (:class:`~blackbox.transport.zenoh_bus.ZenohBus`)
    across networks. Readers have ``take(N=...)``, writers ``write(sample)``."""

    def writer(self, name: str) -> Any: ...

    def reader(self, name: str, qos: Any = None) -> Any: ...

    def waiter(self, readers: Iterable[Any]) -> Waiter: ...

    def close(self) -> None: ...


@dataclass
class DdsWaiter:
    """A Cyclone wait set on the readers' unread samples."""

    waitset: WaitSet

    def wait(self, seconds: float) -> None:
        self.waitset.wait(duration(seconds=seconds))


@dataclass
class Bus:
    """A participant with one publisher and one subscriber in the configured partition."""

    settings: TransportSettings
    participant: DomainParticipant
    domain: Domain | None
    publisher: Publisher
    subscriber: Subscriber
    topics: dict[str, Topic[Any]] = field(default_factory=dict)
    interface: str | None = None
    """The interface Cyclone's receiving sockets are pinned to (``None``: not pinned)."""
    pin_errors: tuple[str, ...] = ()

    @classmethod
    def open(cls, settings: TransportSettings) -> Bus:
        config = settings.cyclone_config
        if config is None and not os.environ.get("CYCLONEDDS_URI"):
            config = LOOPBACK_CONFIG
        limit_malformed_packet_logging()
        before = set(udp_wildcard_sockets())
        domain = None
        if config is not None:
            try:
                domain = Domain(settings.domain_id, config)
            except DDSException:
                domain = None  # this process already created the domain
        participant = DomainParticipant(settings.domain_id)
        interface = configured_interface(config or os.environ.get("CYCLONEDDS_URI", ""))
        errors = tuple(pin_new_sockets(before, interface)) if interface else ()
        qos = partition(settings.partition)
        return cls(settings, participant, domain, Publisher(participant, qos),
                   Subscriber(participant, qos), interface=interface, pin_errors=errors)

    def topic(self, name: str) -> Topic[Any]:
        topic = self.topics.get(name)
        if topic is None:
            topic = Topic(self.participant, name, ALL_TOPICS[name])
            self.topics[name] = topic
        return topic

    def writer(self, name: str) -> DataWriter[Any]:
        return DataWriter(self.publisher, self.topic(name), qos_for(name))

    def reader(self, name: str, qos: Any = None) -> DataReader[Any]:
        return DataReader(self.subscriber, self.topic(name), qos or qos_for(name))

    def waiter(self, readers: Iterable[Any]) -> DdsWaiter:
        waitset = WaitSet(self.participant)
        mask = SampleState.NotRead | ViewState.Any | InstanceState.Any
        for reader in readers:
            waitset.attach(ReadCondition(reader, mask))
        return DdsWaiter(waitset)

    def writers(self, names: Mapping[str, Any]) -> dict[type, DataWriter[Any]]:
        return {ALL_TOPICS[n]: self.writer(n) for n in names}

    def close(self) -> None:
        """Delete the participant and everything in it now (not whenever GC runs), so
        remote readers see the writers leave."""
        participant = self.participant
        if participant is not None:
            self.topics.clear()
            participant.__del__()
        self.domain = None


def matched_both_ways(writer: DataWriter[Any], reader: DataReader[Any]) -> bool:
    """Some participant reads what ``writer`` writes *and* writes what ``reader`` reads.

    A request/reply pair over volatile topics needs both: a reply written before the
    robot's reply writer has discovered this reader is lost, and discovery of the two
    directions completes at different moments."""
    def participants(handles: list[int], data: Any) -> set[Any]:
        keys = set()
        for handle in handles:
            endpoint = data(handle)
            if endpoint is not None:
                keys.add(endpoint.participant_key)
        return keys
    return bool(participants(writer.get_matched_subscriptions(),
                             writer.get_matched_subscription_data)
                & participants(reader.get_matched_publications(),
                               reader.get_matched_publication_data))

