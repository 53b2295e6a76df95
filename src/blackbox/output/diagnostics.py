"""``RosDiagnosticsSink``: the black box's verdicts as ROS 2 ``/diagnostics``.

``rqt_robot_monitor``, ``diagnostic_aggregator`` and Foxglove read
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``. This sink publishes one there,
with plain Cyclone DDS (no rclpy, no node: on the wire a ROS 2 topic ``/diagnostics`` is the
DDS topic ``rt/diagnostics`` of type ``diagnostic_msgs::msg::dds_::DiagnosticArray_``, whose
layout comes from the ``rosbags`` type store). Every robot health entity (each node, the
robot itself) is one ``DiagnosticStatus`` named ``blackbox/<robot id>/<entity>``; its
level maps the UCMS health status of :mod:`blackbox.health`:

=================  ====================  =========================================
UCMS               DiagnosticStatus      meaning
=================  ====================  =========================================
OPERATIONAL        OK (0)                every known characteristic is ok
DEGRADED           WARN (1)              some characteristic is failing
NOT_OPERATIONAL    ERROR (2)             diagnosed, or every characteristic failing
UNKNOWN            STALE (3)             no verdict (yet, or no longer)
=================  ====================  =========================================

``values`` hold each characteristic's latest verdict (``hz /usb_cam/image_raw`` ->
``ok``/``FAILING: ...``). The array goes out once a second and at once when a level
changes. Off by default (``blackbox run --publish-diagnostics``): the DDS writer is
visible to ROS 2 tools as an endpoint (not as a node), which a user asks for by turning it on.
"""

from __future__ import annotations

import threading
import time
from abc import abstractmethod
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from cyclonedds.core import DDSException
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from blackbox.health.describe import ObserverDescription
from blackbox.health.mapping import HealthMapper
from blackbox.health.status import Health, Hysteresis
from blackbox.model import Diagnosis, Observation
from blackbox.sinks import SinkBase
from blackbox.sources.ros2.idl import IdlTypes
from blackbox.sources.ros2.source import cyclone_config_for_ros2

__all__ = ["LEVEL_OF_HEALTH", "DiagnosticStatusEntry", "DiagnosticsSinkBase",
           "RosDiagnosticsSink"]

OK, WARN, ERROR, STALE = 0, 1, 2, 3

LEVEL_OF_HEALTH: dict[Health, int] = {
    Health.OPERATIONAL: OK,
    Health.DEGRADED: WARN,
    Health.NOT_OPERATIONAL: ERROR,
    Health.UNKNOWN: STALE,
}

_MESSAGES = {OK: "operational", WARN: "degraded", ERROR: "not operational",
             STALE: "no verdict"}


@dataclass(frozen=True, slots=True)
class DiagnosticStatusEntry:
    """One ``diagnostic_msgs/DiagnosticStatus``, independent of the ROS version."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


class DiagnosticsSinkBase(SinkBase):
    """The verdict -> ``DiagnosticStatus`` logic shared by the ROS 1 and ROS 2 publishers.

    Keeps each entity's UCMS health (:class:`HealthMapper`) and each characteristic's latest
    verdict; hands a transport the statuses once every ``period`` and at once when a level
    changes. A transport implements :meth:`_write`.
    """

    def __init__(self, robot_id: str, *, descriptions: Iterable[ObserverDescription] = (),
                 hysteresis: Hysteresis | None = None, period: float = 1.0,
                 clock: Callable[[], float] = time.time) -> None:
        self.robot_id = robot_id
        self.period = period
        self.clock = clock
        self.mapper = HealthMapper(robot_id, descriptions=descriptions, hysteresis=hysteresis)
        self.published = 0
        self.write_errors = 0
        self._verdicts: dict[str, dict[str, str]] = {}
        self._levels: dict[str, int] = {}
        self._next = 0.0
        self._lock = threading.Lock()
        self.mapper.start(clock())

    # ---- sink --------------------------------------------------------------------------------

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self._lock:
            self.mapper.observations(now, observations)
            for obs in observations:
                entity = self.mapper.entity_of(obs.resource)
                label = f"{obs.observer} {obs.resource.label()}"
                verdict = (f"FAILING: {obs.message}" if obs.faulty and obs.message
                           else obs.code.name.lower() if obs.faulty else "ok")
                self._verdicts.setdefault(entity, {})[label] = verdict
            self.mapper.expire(now)
            self._maybe_publish(now)

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        with self._lock:
            self.mapper.diagnosis(diagnosis)
            self._maybe_publish(diagnosis.time)

    # ---- publishing --------------------------------------------------------------------------

    def levels(self) -> dict[str, int]:
        """Each entity's current ``DiagnosticStatus`` level (``""`` is the robot)."""
        return {name: LEVEL_OF_HEALTH[h] for name, h in self.mapper.entities().items()}

    def statuses(self, levels: dict[str, int]) -> list[DiagnosticStatusEntry]:
        """One status per entity, named ``blackbox/<robot id>/<entity>``."""
        out = []
        for entity, level in sorted(levels.items()):
            verdicts = self._verdicts.get(entity, {})
            failing = [f"{k}: {v}" for k, v in sorted(verdicts.items()) if v != "ok"]
            message = _MESSAGES[level] + (f" ({'; '.join(failing)})" if failing else "")
            out.append(DiagnosticStatusEntry(
                level=level, name=f"blackbox/{self.robot_id}/{entity.strip('/') or 'robot'}",
                message=message[:1024], hardware_id=self.robot_id,
                values=tuple((k, v[:512]) for k, v in sorted(verdicts.items()))))
        return out

    def _maybe_publish(self, now: float) -> None:
        levels = self.levels()
        if levels == self._levels and now < self._next:
            return
        self._levels = levels
        self._next = now + self.period
        written = self._write(now, self.statuses(levels))
        if written:
            self.published += 1
        elif written is not None:
            self.write_errors += 1

    @abstractmethod
    def _write(self, now: float, statuses: list[DiagnosticStatusEntry]) -> bool | None:
        """Send one ``DiagnosticArray`` stamped ``now``; ``False`` when it failed, ``None``
        when nothing was sent (closed)."""


class RosDiagnosticsSink(DiagnosticsSinkBase):
    """Publishes one robot's health as ``diagnostic_msgs/DiagnosticArray`` on ROS 2
    ``/diagnostics`` of DDS domain ``domain_id``."""

    def __init__(self, robot_id: str, *, domain_id: int = 0,
                 descriptions: Iterable[ObserverDescription] = (),
                 hysteresis: Hysteresis | None = None, period: float = 1.0,
                 cyclone_config: str | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        types = IdlTypes()
        self._array: Any = types.struct("diagnostic_msgs/msg/DiagnosticArray")
        self._status: Any = types.struct("diagnostic_msgs/msg/DiagnosticStatus")
        self._key_value: Any = types.struct("diagnostic_msgs/msg/KeyValue")
        self._header: Any = types.struct("std_msgs/msg/Header")
        self._stamp: Any = types.struct("builtin_interfaces/msg/Time")
        self._domain: Domain | None = None
        try:
            self._domain = Domain(domain_id, cyclone_config_for_ros2(cyclone_config))
        except DDSException:
            self._domain = None  # this process already runs the domain
        self._participant: DomainParticipant | None = DomainParticipant(domain_id)
        topic = Topic(self._participant, "rt/diagnostics", self._array)
        self._writer: DataWriter[Any] = DataWriter(
            self._participant, topic,
            Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                Policy.Durability.Volatile, Policy.History.KeepLast(10)))
        super().__init__(robot_id, descriptions=descriptions, hysteresis=hysteresis,
                         period=period, clock=clock)

    def close(self) -> None:
        with self._lock:
            participant, self._participant = self._participant, None
            if participant is not None:
                participant.__del__()
            self._domain = None

    def _write(self, now: float, statuses: list[DiagnosticStatusEntry]) -> bool | None:
        if self._participant is None:
            return None
        sec = int(now)
        header = self._header(stamp=self._stamp(sec=sec, nanosec=int((now - sec) * 1e9)),
                              frame_id="")
        array = self._array(header=header, status=[
            self._status(level=s.level, name=s.name, message=s.message,
                         hardware_id=s.hardware_id,
                         values=[self._key_value(key=k, value=v) for k, v in s.values])
            for s in statuses])
        try:
            self._writer.write(array)
        except DDSException:
            return False
        return True
