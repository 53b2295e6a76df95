"""Quality of service of every topic, after thesis Table 6.6.

=========================================  ==================  ==========================
topics                                     Table 6.6           here
=========================================  ==================  ==========================
Entity/Characteristic/Threshold            Durability,         transient-local, keep last
Specification, entity/characteristic       History,            1 per instance, reliable
extension                                  Reliability
Monitored Entity, Characteristic,          Durability,         the same (see below)
Threshold                                  History
Threshold Exceedence Event, Failure        History             volatile, keep last 64 per
Event, event extension                                         instance, reliable
remote interface (log request/reply,       (not UCMS)          volatile, keep all, reliable
IBIT command/result)
=========================================  ==================  ==========================

Table 6.6 lists no Reliability for the durable status topics, but Cyclone delivers the
transient-local history to a late joiner only over a reliable connection, and the full
state for late joiners is the point of durability here; so they are reliable too.
``DurabilityService.history`` is set to the same depth as ``History``: Cyclone's default of
KeepLast(1) would otherwise cut what a late joiner receives.
"""

from __future__ import annotations

from cyclonedds.qos import Policy, Qos
from cyclonedds.util import duration

EVENT_DEPTH = 64
_BLOCKING = duration(seconds=1)


def _durable(depth: int) -> Qos:
    return Qos(
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(depth),
        Policy.Reliability.Reliable(_BLOCKING),
        Policy.DurabilityService(cleanup_delay=0, history=Policy.History.KeepLast(depth),
                                 max_samples=-1, max_instances=-1, max_samples_per_instance=-1),
    )


STATE = _durable(1)
"""Specifications, status topics and their extensions: latest sample per instance, durable."""

SIGNATURE = Qos(
    Policy.Durability.TransientLocal,
    Policy.History.KeepLast(EVENT_DEPTH),
    Policy.Reliability.Reliable(_BLOCKING),
    Policy.DurabilityService(cleanup_delay=0, history=Policy.History.KeepLast(1),
                             max_samples=-1, max_instances=-1, max_samples_per_instance=-1),
)
"""Sample signatures: a connected station must get the signature of every sample it may
get (a state changing faster than the link keeps only its latest sample, but each of them
needs its own signature), so the writer keeps up to 64 per instance for retransmission;
a late joiner gets the latest per instance, the one of the durable state it receives."""

EVENT = Qos(
    Policy.Durability.Volatile,
    Policy.History.KeepLast(EVENT_DEPTH),
    Policy.Reliability.Reliable(_BLOCKING),
)
"""Threshold exceedence and failure events: none lost while a reader is connected."""

COMMAND = Qos(
    Policy.Durability.Volatile,
    Policy.History.KeepAll,
    Policy.Reliability.Reliable(duration(seconds=5)),
)
"""Log requests and replies, IBIT commands and results."""

EVENT_TOPICS = frozenset({"C_Threshold_Exceedence_Event", "C_Failure_Event",
                          "C_Preventive_Maintenance_Recommended_Event",
                          "BlackBox_Event_Extension"})
COMMAND_TOPICS = frozenset({"C_Monitored_Entity_run_IBIT", "BlackBox_Log_Request",
                            "BlackBox_Log_Reply", "BlackBox_IBIT_Result",
                            "BlackBox_IBIT_Request"})


def qos_for(topic: str) -> Qos:
    if topic == "BlackBox_Sample_Signature":
        return SIGNATURE
    if topic in EVENT_TOPICS:
        return EVENT
    if topic in COMMAND_TOPICS:
        return COMMAND
    return STATE


def partition(name: str) -> Qos:
    return Qos(Policy.Partition([name]))
