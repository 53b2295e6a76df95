"""``Ros1DiagnosticsSink``: the black box's verdicts on ROS 1 ``/diagnostics``.

The same statuses as the ROS 2 sink (:class:`~blackbox.output.diagnostics.DiagnosticsSinkBase`:
one ``DiagnosticStatus`` per health entity, level from the UCMS status, once a second and at
once on a level change), serialized as ROS 1 ``diagnostic_msgs/DiagnosticArray`` by the
``rosbags`` type store and served by :class:`~blackbox.output.ros1_publisher.Ros1TopicPublisher`
(no rospy). The publisher registers with the ROS 1 master under a unique caller id
(``/blackbox_diagnostics_<host>_<pid>_<n>``): the black box then shows up in ``rosnode list``
and ``rostopic info /diagnostics``, which the user accepts by passing
``--publish-diagnostics``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

from rosbags.typesys import Stores, get_typestore

from blackbox.health.describe import ObserverDescription
from blackbox.health.status import Hysteresis
from blackbox.output.diagnostics import DiagnosticsSinkBase, DiagnosticStatusEntry
from blackbox.output.ros1_publisher import Ros1TopicPublisher
from blackbox.sources.ros1.callerid import unique_caller_id

__all__ = ["CALLER_ID_PREFIX", "Ros1DiagnosticsSink"]

CALLER_ID_PREFIX = "/blackbox_diagnostics"
_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"


class Ros1DiagnosticsSink(DiagnosticsSinkBase):
    """Publishes one robot's health as ``diagnostic_msgs/DiagnosticArray`` on the ROS 1
    ``/diagnostics`` of the master at ``master_uri``."""

    def __init__(self, robot_id: str, master_uri: str, *,
                 descriptions: Iterable[ObserverDescription] = (),
                 hysteresis: Hysteresis | None = None, period: float = 1.0,
                 caller_id: str | None = None, host: str = "127.0.0.1",
                 clock: Callable[[], float] = time.time) -> None:
        store = get_typestore(Stores.ROS1_NOETIC)
        self._store = store
        self._types: Any = store.types
        definition, md5sum = store.generate_msgdef(_ARRAY, ros_version=1)
        self._seq = 0
        self.publisher = Ros1TopicPublisher(
            master_uri, caller_id or unique_caller_id(CALLER_ID_PREFIX), "/diagnostics",
            "diagnostic_msgs/DiagnosticArray", md5sum, definition, latching=True, host=host)
        super().__init__(robot_id, descriptions=descriptions, hysteresis=hysteresis,
                         period=period, clock=clock)
        self.publisher.start()

    def close(self) -> None:
        self.publisher.close()

    def serialize(self, now: float, statuses: list[DiagnosticStatusEntry]) -> bytes:
        """One ROS 1 ``DiagnosticArray`` message stamped ``now``."""
        t = self._types
        sec = int(now)
        self._seq += 1
        header = t["std_msgs/msg/Header"](
            seq=self._seq, stamp=t["builtin_interfaces/msg/Time"](
                sec=sec, nanosec=int((now - sec) * 1e9)), frame_id="")
        array = t[_ARRAY](header=header, status=[
            t["diagnostic_msgs/msg/DiagnosticStatus"](
                level=s.level, name=s.name, message=s.message, hardware_id=s.hardware_id,
                values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=v)
                        for k, v in s.values])
            for s in statuses])
        return bytes(self._store.serialize_ros1(array, _ARRAY))

    def _write(self, now: float, statuses: list[DiagnosticStatusEntry]) -> bool:
        self.publisher.publish(self.serialize(now, statuses))
        return True
