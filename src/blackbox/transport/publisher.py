"""``DdsHealthSink``: the black box's health, as UCMS samples on a DDS domain.

Records are mapped (``blackbox.health.mapping``) and written on the pipeline thread: a
write is tens of microseconds and keeps the fault-to-station latency down. A service thread
answers remote log requests (from the recorder's store) and run_IBIT commands.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from cyclonedds.core import DDSException

from blackbox.config.node import ConfigNode
from blackbox.health.describe import ObserverDescription, describe_observers
from blackbox.health.extension import EXTENSION_TOPICS
from blackbox.health.identity import EventLedger
from blackbox.health.mapping import FailureActions, HealthMapper
from blackbox.health.status import Hysteresis
from blackbox.health.types import (
    UCMS_TOPICS,
    C_IBIT_Result,
    C_Monitored_Entity_run_IBIT,
    T_HealthStatus,
    T_Monitored_Entity_StateType,
    datetime_of,
)
from blackbox.model import BlackBoxEvent, Diagnosis, Observation
from blackbox.sinks import SinkBase
from blackbox.transport.auth import AccessPolicy, RequestVerifier, load_private_key
from blackbox.transport.buses import open_bus
from blackbox.transport.cdr_encoder import sample_writer
from blackbox.transport.ibit import IbitService
from blackbox.transport.logservice import DEFAULT_CHUNK, LogService, LogSource, open_store
from blackbox.transport.participant import (
    ALL_TOPICS,
    TOPIC_OF_TYPE,
    HealthBus,
    TransportSettings,
)
from blackbox.transport.provenance import SIGNATURE_TOPIC, SampleSigner
from blackbox.transport.qos import EVENT_TOPICS
from blackbox.transport.zenoh_bus import ZenohSettings

EVENT_INSTANCES_KEPT = 256
OFF = T_Monitored_Entity_StateType.L_Monitored_Entity_StateType_OFF
PUBLISHED_TOPICS = [name for name in (*UCMS_TOPICS, *EXTENSION_TOPICS)
                    if name != "C_Monitored_Entity_run_IBIT"]


def replay_file_for(signing_key_file: str | Path | None,
                    log_store_path: str | Path | None) -> Path | None:
    """Where the accepted request nonces are kept across restarts: beside the robot's key,
    else beside the recorder's log, else nowhere (memory only)."""
    for base in (signing_key_file, log_store_path):
        if base is not None:
            path = Path(base)
            return path.with_name(path.name + ".nonces")
    return None


class DdsHealthSink(SinkBase):
    """Publishes one robot's health over DDS and serves its remote interface.

    ``descriptions`` (see :func:`blackbox.health.describe.describe_observers`) give
    units, thresholds, noise and filters before the first observation; without them
    characteristics are created from the observations alone, without thresholds.
    ``log_store_path`` (or ``log_source``) enables remote log requests; ``on_ibit``
    (typically ``pipeline.evaluate_all``) enables run_IBIT. Both are answered only as
    ``access`` allows (default: nobody; see :mod:`blackbox.transport.auth`).
    ``signing_key_file`` (``blackbox keygen``): the robot's own key; every sample and
    reply is then signed (:mod:`blackbox.transport.provenance`) so that stations that
    enrolled the key can tell it from a forgery. ``replay_file``: where accepted request
    nonces survive a restart (default: :func:`replay_file_for`). ``bus``: a bus already
    open for this robot (e.g. :meth:`ZenohBus.sharing`, one Zenoh session for many robots
    of a gateway or a simulated fleet) instead of one of its own.
    """

    def __init__(
        self,
        robot_id: str,
        *,
        domain_id: int = 0,
        partition: str = "blackbox",
        cyclone_config: str | None = None,
        descriptions: Iterable[ObserverDescription] = (),
        owners: Mapping[str, str] | None = None,
        failure_actions: Mapping[str, FailureActions] | None = None,
        hysteresis: Hysteresis | None = None,
        logging_interval: float | None = None,
        log_store_path: str | Path | None = None,
        log_source: LogSource | None = None,
        log_chunk_size: int = DEFAULT_CHUNK,
        on_ibit: Callable[[], Sequence[Observation]] | None = None,
        access: AccessPolicy | None = None,
        clock: Callable[[], float] = time.time,
        ledger: EventLedger | None = None,
        signing_key_file: str | Path | None = None,
        replay_file: str | Path | None = None,
        zenoh: ZenohSettings | None = None,
        bus: HealthBus | None = None,
    ) -> None:
        if not robot_id:
            raise ValueError("robot id must not be empty")
        self.robot_id = robot_id
        self.clock = clock
        self.signer: SampleSigner | None = None
        if signing_key_file is not None:
            self.signer = SampleSigner(load_private_key(Path(signing_key_file)), robot_id,
                                       clock=clock)
        self.on_ibit = on_ibit
        if zenoh is not None:  # a robot runs and records whether or not a router is up
            zenoh = dataclasses.replace(zenoh, router_optional=True)
        self.settings = TransportSettings(domain_id, partition, cyclone_config, zenoh)
        self.mapper = HealthMapper(robot_id, descriptions=descriptions, owners=owners,
                                   failure_actions=failure_actions, hysteresis=hysteresis,
                                   logging_interval=logging_interval, ledger=ledger)
        self.ledger = self.mapper.ledger
        self.bus = bus if bus is not None else open_bus(self.settings, robot_id)
        self._writers: dict[type, Any] = {
            t: self.bus.writer(name) for name, t in ALL_TOPICS.items()
            if (name.startswith("C_") and name != "C_Monitored_Entity_run_IBIT")
            or name in ("BlackBox_Entity_Description", "BlackBox_Characteristic_Extension",
                        "BlackBox_Event_Extension")}
        self._signatures = self.bus.writer(SIGNATURE_TOPIC) if self.signer else None
        # samples are encoded by precompiled encoders, not the per-sample IDL machinery
        # (a Zenoh writer has none of Cyclone's internals: its own write is used)
        self._write_sample: dict[type, Callable[[Any], None]] = {
            t: sample_writer(w) for t, w in self._writers.items()}
        self._events: deque[tuple[Any, Any]] = deque()
        self._lock = threading.RLock()
        self.written = 0
        self.write_errors = 0
        self.last_error: str | None = None
        self._closed = False
        self._now = clock()
        self._write(self.mapper.start(self._now))

        self._stop = threading.Event()
        self._services: list[Any] = []
        replay = Path(replay_file) if replay_file is not None else \
            replay_file_for(signing_key_file, log_store_path)
        self.verifier = RequestVerifier(robot_id, access or AccessPolicy(), nonce_file=replay)
        if log_source is not None or log_store_path is not None:
            opener = (lambda: log_source) if log_source is not None else \
                (lambda: open_store(str(log_store_path)))
            self._services.append(LogService(self.bus, robot_id, opener, log_chunk_size,
                                             self.verifier, signer=self.signer))
        if on_ibit is not None:
            self._services.append(IbitService(self.bus, robot_id, self._run_ibit,
                                              self.verifier, signer=self.signer))
        self._thread: threading.Thread | None = None
        if self._services:
            self._thread = threading.Thread(target=self._serve, name="blackbox-dds-service",
                                            daemon=True)
            self._thread.start()

    # ---- configuration ----------------------------------------------------------------------

    @classmethod
    def from_config(cls, section: ConfigNode | None, robot_id: str, *,
                    observers: ConfigNode | None = None, **kwargs: Any) -> DdsHealthSink:
        """A sink from the native ``transport:`` section (keys in docs/health.md) and the
        ``observers:`` section it takes thresholds and units from."""
        return cls(robot_id, **transport_options(section), descriptions=describe_observers(
            observers), **kwargs)

    # ---- sink ----------------------------------------------------------------------------------

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self._lock:
            self._now = now
            self._write(self.mapper.observations(now, observations))
            self._write(self.mapper.expire(now))

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self._lock:
            self._write(self.mapper.diagnosis(diagnosis))

    def on_event(self, event: BlackBoxEvent) -> None:
        return None

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        with self._lock:
            self._write([self._offline(s) for s in self.mapper.set_bit_in_progress(
                self._now, False)])
            time.sleep(0.05)  # let the last samples leave before the participant goes
            self.bus.close()

    # ---- internals ---------------------------------------------------------------------------

    @staticmethod
    def _offline(sample: Any) -> Any:
        sample.A_MonitoredEntityState = OFF
        sample.A_healthStatus = T_HealthStatus.L_HealthStatus_UNKNOWN
        return sample

    def _write(self, samples: Iterable[Any]) -> None:
        for sample in samples:
            writer = self._writers.get(type(sample))
            if writer is None:
                continue
            topic = TOPIC_OF_TYPE[type(sample)]
            signature = None
            try:
                if self.signer is not None and self._signatures is not None:
                    # the signature first: a station holds a sample until its signature
                    # arrives, so this order keeps that wait short
                    signature = self.signer.sign(topic, sample)
                    self._signatures.write(signature)
                self._write_sample[type(sample)](sample)
                self.written += 1
            except DDSException as exc:
                self.write_errors += 1
                self.last_error = str(exc)
                continue
            if topic in EVENT_TOPICS:
                self._events.append((writer, sample))
                if signature is not None and self._signatures is not None:
                    self._events.append((self._signatures, signature))
                while len(self._events) > EVENT_INSTANCES_KEPT:
                    old_writer, old = self._events.popleft()
                    with contextlib.suppress(DDSException):
                        old_writer.unregister_instance(old)

    def _run_ibit(self, command: C_Monitored_Entity_run_IBIT) -> C_IBIT_Result:
        assert self.on_ibit is not None
        with self._lock:
            self._write(self.mapper.set_bit_in_progress(self._now, True))
        error = ""
        try:
            observations = list(self.on_ibit())
        except Exception as exc:  # a failing test is an answer, not a crash
            observations, error = [], f"built-in test failed: {exc}"
        with self._lock:
            now = max([self._now, *(o.time for o in observations)])
            self._now = now
            self._write(self.mapper.observations(now, observations))
            self._write(self.mapper.set_bit_in_progress(now, False))
            names = self.mapper.ids.name_of(command.A_recipientID)
            entity = names[1] if names and names[0] == "entity" else ""
            health = self.mapper.entities().get(entity, self.mapper.robot(now, []).health)
        failed = [o for o in observations if o.faulty]
        report = [f"{'FAULT' if o.faulty else 'OK'} {o.observer} {o.resource.label()} "
                  f"{o.code.name} {o.message}".strip() for o in observations]
        if error:
            report.append(error)
        return C_IBIT_Result(A_recipientID=command.A_recipientID,
                             A_referenceNum=command.A_referenceNum,
                             A_sourceID=self.mapper.ids.robot(),
                             A_timeOfDataGeneration=datetime_of(self.clock()),
                             A_healthStatus=T_HealthStatus(int(health)),
                             A_observations=len(observations), A_failed=len(failed),
                             A_report=report)

    def _serve(self) -> None:
        waiter = self.bus.waiter(reader for service in self._services
                                 for reader in getattr(service, "readers", (service.reader,)))
        while not self._stop.is_set():
            waiter.wait(0.2)
            for service in self._services:
                try:
                    service.poll()
                except Exception as exc:  # keep serving whatever a request did
                    self.last_error = f"{type(service).__name__}: {exc}"


def transport_options(section: ConfigNode | None,
                      base_dir: Path = Path(".")) -> dict[str, Any]:
    """Keyword arguments of :class:`DdsHealthSink` from a native ``transport:`` section."""
    if section is None:
        return {}
    section.check_keys(["domain_id", "partition", "cyclone_config", "owners",
                        "failure_actions", "status", "logging_interval", "log_store",
                        "log_chunk_size", "access", "key_file"])
    if (node := section.get("access")) is not None:
        out_access = AccessPolicy.from_config(node, base_dir)
    else:
        out_access = None
    out: dict[str, Any] = {}
    if (node := section.get("domain_id")) is not None:
        out["domain_id"] = node.int(min=0, max=232)
    if (node := section.get("partition")) is not None:
        out["partition"] = node.str()
    if (node := section.get("cyclone_config")) is not None:
        out["cyclone_config"] = node.str()
    if (node := section.get("owners")) is not None:
        owners: dict[str, str] = {}
        for node_name, topics in node.items():
            for topic in topics.str_list():
                owners[topic] = node_name
        out["owners"] = owners
    if (node := section.get("failure_actions")) is not None:
        actions: dict[str, FailureActions] = {}
        for entity, spec in node.items():
            spec.check_keys(["consequence", "operator_action", "maintenance_action",
                             "documentation_uri"])
            actions[entity] = FailureActions(**{k: v.str() for k, v in spec.items()
                                                if not v.is_null})
        out["failure_actions"] = actions
    if (node := section.get("status")) is not None:
        node.check_keys(["raise_after", "clear_after", "stale_after"])
        kw: dict[str, Any] = {}
        for key in ("raise_after", "clear_after"):
            if (v := node.get(key)) is not None:
                kw[key] = v.int(min=1)
        if (v := node.get("stale_after")) is not None:
            kw["stale_after"] = v.float(min=0.0, min_exclusive=True)
        out["hysteresis"] = Hysteresis(**kw)
    if (node := section.get("logging_interval")) is not None:
        out["logging_interval"] = node.float(min=0.0, min_exclusive=True)
    if (node := section.get("log_store")) is not None:
        out["log_store_path"] = node.str()
    if (node := section.get("log_chunk_size")) is not None:
        out["log_chunk_size"] = node.int(min=1, max=10_000)
    if out_access is not None:
        out["access"] = out_access
    if (node := section.get("key_file")) is not None:
        path = Path(node.str())
        path = path if path.is_absolute() else base_dir / path
        if not path.is_file():
            raise node.error(f"cannot read the robot's key {path}")
        out["signing_key_file"] = path
    return out
