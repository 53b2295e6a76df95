"""The UCMS data model (thesis Appendix A) as Cyclone DDS types, plus the black box's remote
interface types.

Every struct and enum of ``P_UCMS_PSM`` is here with its IDL name, so a station written
against the NGVA IDL reads what the black box writes. ``LDM_Common.idl`` is not part of the
thesis; its two structured types are defined as NGVA uses them (an identifier is a resource
id plus an instance id, a date-time is seconds plus nanoseconds since the Unix epoch) and its
scalar typedefs map onto the obvious DDS types (``T_Int32``/``T_int`` int32, ``T_Double``
double, ``T_Boolean`` boolean, the string typedefs unbounded strings).

The log request/reply and built-in test result types are not UCMS (the data model has only
the ``run_IBIT`` command); they live in module ``P_BlackBox_Remote`` on their own topics, so
a plain UCMS reader never sees them.

Topic names are the struct names (``C_Monitored_Entity`` ...), listed in :data:`UCMS_TOPICS`
and :data:`REMOTE_TOPICS`.

This module deliberately has no ``from __future__ import annotations``: the IDL machinery
reads the field annotations as real types.
"""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlEnum, IdlStruct
from cyclonedds.idl.annotations import key
from cyclonedds.idl.types import int32, int64, sequence, uint8, uint32

# ---- P_LDM_Common ----------------------------------------------------------------------


@dataclass
class T_IdentifierType(IdlStruct, typename="P_LDM_Common.T_IdentifierType"):
    """A source id: which resource (here: which robot) and which instance within it."""

    A_resourceId: int32 = 0
    A_instanceId: int32 = 0


@dataclass
class T_DateTimeType(IdlStruct, typename="P_LDM_Common.T_DateTimeType"):
    """Seconds and nanoseconds since the Unix epoch."""

    A_second: int64 = 0
    A_nanoseconds: int32 = 0


NO_ID = T_IdentifierType(0, 0)
"""The null identifier: "no such object" in reference fields."""


def datetime_of(t: float) -> T_DateTimeType:
    seconds = int(t // 1)
    nanos = round((t - seconds) * 1e9)
    if nanos >= 1_000_000_000:
        seconds, nanos = seconds + 1, nanos - 1_000_000_000
    return T_DateTimeType(seconds, nanos)


def seconds_of(dt: T_DateTimeType) -> float:
    return dt.A_second + dt.A_nanoseconds * 1e-9


# ---- P_UCMS_PSM enums ------------------------------------------------------------------


class T_Monitored_Entity_StateType(IdlEnum, typename="P_UCMS_PSM.T_Monitored_Entity_StateType"):
    L_Monitored_Entity_StateType_ON = 0
    L_Monitored_Entity_StateType_OFF = 1


class T_HealthStatus(IdlEnum, typename="P_UCMS_PSM.T_HealthStatus"):
    L_HealthStatus_OPERATIONAL = 0
    L_HealthStatus_DEGRADED = 1
    L_HealthStatus_NOT_OPERATIONAL = 2
    L_HealthStatus_UNKNOWN = 3


class T_MonitoredDataWarningLevel(IdlEnum, typename="P_UCMS_PSM.T_MonitoredDataWarningLevel"):
    L_MonitoredDataWarningLevel_NO_WARNING = 0
    L_MonitoredDataWarningLevel_PRE_WARNING = 1
    L_MonitoredDataWarningLevel_WARNING = 2


class T_ThresholdType(IdlEnum, typename="P_UCMS_PSM.T_ThresholdType"):
    L_ThresholdType_MIN = 0
    L_ThresholdType_MAX = 1


class T_BITType(IdlEnum, typename="P_UCMS_PSM.T_BITType"):
    L_BITType_C_BIT = 0
    L_BITType_P_BIT = 1
    L_BITType_I_BIT = 2


class T_MonitoredCharacteristicKind(IdlEnum, typename="P_UCMS_PSM.T_MonitoredCharacteristicKind"):
    L_MonitoredCharacteristicKind_INSTANT = 0
    L_MonitoredCharacteristicKind_CUMULATIVE = 1


# ---- P_UCMS_PSM structs ------------------------------------------------------------------


def _ids() -> list[T_IdentifierType]:
    return []


@dataclass
class C_Monitored_Entity_run_IBIT(IdlStruct, typename="P_UCMS_PSM.C_Monitored_Entity_run_IBIT"):
    """Command: run an initiated built-in test on the entity ``A_recipientID``."""

    A_recipientID: T_IdentifierType
    key("A_recipientID")
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_referenceNum: int32 = 0
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)


@dataclass
class C_Monitored_Entity(IdlStruct, typename="P_UCMS_PSM.C_Monitored_Entity"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_healthStatus: T_HealthStatus = T_HealthStatus.L_HealthStatus_UNKNOWN
    A_bitInProgress: bool = False
    A_MonitoredEntityState: T_Monitored_Entity_StateType = (
        T_Monitored_Entity_StateType.L_Monitored_Entity_StateType_ON)
    A_failureEvents_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)
    A_specification_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_installedSoftwares_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)
    A_preventiveMaintenanceRecommendedEvents_sourceID: sequence[T_IdentifierType] = field(
        default_factory=_ids)
    A_monitoredCharacteristics_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)


@dataclass
class C_Failure_Event(IdlStruct, typename="P_UCMS_PSM.C_Failure_Event"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_eventOccurrenceDate: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_standardFaultCode: float = 0.0
    A_proprietaryFaultCode: str = ""
    A_predictedFailure: bool = False
    A_failureDescription: str = ""
    A_causeDescription: str = ""
    A_operationalConsequenceDescription: str = ""
    A_operatorActionDescription: str = ""
    A_maintenanceActionDescription: str = ""
    A_complementaryInformation: str = ""
    A_eventDocumentationURI: str = ""
    A_monitoredEntity_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Installed_Software(IdlStruct, typename="P_UCMS_PSM.C_Installed_Software"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_serialNumber: int32 = 0
    A_version: int32 = 0
    A_configuration: int32 = 0
    A_subSystem_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Preventive_Maintenance_Recommended_Event(
        IdlStruct, typename="P_UCMS_PSM.C_Preventive_Maintenance_Recommended_Event"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_dataDescriptor: str = ""
    A_dataUnit: str = ""
    A_dataValue: float = 0.0
    A_preventiveMaintenanceThreshold: float = 0.0
    A_occurrenceDateTime: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_subSystem_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Monitored_Entity_Specification(
        IdlStruct, typename="P_UCMS_PSM.C_Monitored_Entity_Specification"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_cumulativeMonitoredCharacteristicsOutputSupported: bool = False
    A_failureStandardFaultCodeSupported: bool = False
    A_failureProprietaryFaultCodeSupported: bool = False
    A_failureDescriptionSupported: bool = False
    A_failureCauseDescriptionSupported: bool = False
    A_failureOperationalConsequenceDescriptionSupported: bool = False
    A_failureOperatorActionDescriptionSupported: bool = False
    A_failureMaintenanceActionDescriptionSupported: bool = False
    A_failureComplementaryInformationSupported: bool = False
    A_failureDocumentationURISupported: bool = False
    A_installationDateTime: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_specifiedMonitoredEntities_sourceID: sequence[T_IdentifierType] = field(
        default_factory=_ids)


@dataclass
class C_Monitored_Characteristic(IdlStruct, typename="P_UCMS_PSM.C_Monitored_Characteristic"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_value: float = 0.0
    A_monitoredEntity_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_thresholdExceedenceEvents_sourceID: sequence[T_IdentifierType] = field(
        default_factory=_ids)
    A_specification_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Monitored_Characteristic_Specification(
        IdlStruct, typename="P_UCMS_PSM.C_Monitored_Characteristic_Specification"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_unit: str = ""
    A_descriptor: str = ""
    A_publishingIntervalInSeconds: int32 = 0
    A_characteristicKind: T_MonitoredCharacteristicKind = (
        T_MonitoredCharacteristicKind.L_MonitoredCharacteristicKind_INSTANT)
    A_specifiedCharacteristics_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)
    A_thresholds_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)


@dataclass
class C_Threshold(IdlStruct, typename="P_UCMS_PSM.C_Threshold"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_name: str = ""
    A_value: float = 0.0
    A_type: T_ThresholdType = T_ThresholdType.L_ThresholdType_MAX
    A_maxDuration: int32 = 0
    A_maxNumberOfRepetitions: int32 = 0
    A_exceedenceEvents_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)
    A_concernedCharacteristic_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_conditionedThresholds_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)
    A_conditioningThreshold_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_specification_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Threshold_Exceedence_Event(IdlStruct, typename="P_UCMS_PSM.C_Threshold_Exceedence_Event"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_eventOccurrenceDate: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_measuredValue: float = 0.0
    A_exceededThreshold_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_concernedCharacteristic_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_inducedEvents_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)
    A_inducingEvent_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Threshold_Specification(IdlStruct, typename="P_UCMS_PSM.C_Threshold_Specification"):
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_valueThresholdSupported: bool = True
    A_durationThresholdSupported: bool = False
    A_repetitionsThresholdSupported: bool = False
    A_specifiedThresholds_sourceID: sequence[T_IdentifierType] = field(default_factory=_ids)


# ---- P_BlackBox_Remote: log requests and built-in test results (not UCMS) -------------------


@dataclass
class C_Request_Signature(IdlStruct, typename="P_BlackBox_Remote.C_Request_Signature"):
    """Who signed a remote request, until when (ns since the epoch), a nonce, the Ed25519
    signature (``blackbox.transport.auth``). An empty ``A_station`` means unsigned."""

    A_station: str = ""
    A_expiresNs: int64 = 0
    A_nonce: str = ""
    A_signature: sequence[uint8] = field(default_factory=list)


@dataclass
class C_Log_Request(IdlStruct, typename="P_BlackBox_Remote.C_Log_Request"):
    """Ask the black box ``A_recipientID`` (its robot identifier) for recorded entries.

    ``A_requestID``'s resource id names the requesting station, its instance id the request.
    Empty filter strings and zero times mean "no restriction"; ``A_kinds`` empty means all
    kinds.
    """

    A_requestID: T_IdentifierType
    key("A_requestID")
    A_recipientID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_entity: str = ""
    A_characteristic: str = ""
    A_since: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_until: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_kinds: sequence[str] = field(default_factory=list)
    A_maxEntries: uint32 = 0
    A_signed: C_Request_Signature = field(default_factory=C_Request_Signature)


@dataclass
class C_Log_Reply(IdlStruct, typename="P_BlackBox_Remote.C_Log_Reply"):
    """One chunk of the answer to a log request; chunks are numbered from 0.

    ``A_entries`` holds one JSON object per recorded entry (the recorder's ``to_dict``).
    ``A_status`` is ``ok`` or an error message; an error reply is the only, final chunk.
    """

    A_requestID: T_IdentifierType
    key("A_requestID")
    A_chunkIndex: uint32 = 0
    key("A_chunkIndex")
    A_recipientID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_last: bool = True
    A_status: str = "ok"
    A_entries: sequence[str] = field(default_factory=list)
    A_robotSignature: sequence[uint8] = field(default_factory=list)
    """The robot's Ed25519 signature of this chunk with this field empty
    (``blackbox.transport.provenance``); empty: unsigned."""


@dataclass
class C_IBIT_Result(IdlStruct, typename="P_BlackBox_Remote.C_IBIT_Result"):
    """The answer to a ``C_Monitored_Entity_run_IBIT`` command (same reference number)."""

    A_recipientID: T_IdentifierType
    key("A_recipientID")
    A_referenceNum: int32 = 0
    key("A_referenceNum")
    A_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_healthStatus: T_HealthStatus = T_HealthStatus.L_HealthStatus_UNKNOWN
    A_observations: uint32 = 0
    A_failed: uint32 = 0
    A_report: sequence[str] = field(default_factory=list)
    A_robotSignature: sequence[uint8] = field(default_factory=list)
    """The robot's Ed25519 signature of this result with this field empty; empty: unsigned."""


@dataclass
class C_IBIT_Request(IdlStruct, typename="P_BlackBox_Remote.C_IBIT_Request"):
    """A signed ``C_Monitored_Entity_run_IBIT``: the same fields plus the signature."""

    A_recipientID: T_IdentifierType
    key("A_recipientID")
    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_referenceNum: int32 = 0
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_signed: C_Request_Signature = field(default_factory=C_Request_Signature)


UCMS_TOPICS: dict[str, type] = {
    "C_Monitored_Entity": C_Monitored_Entity,
    "C_Monitored_Entity_Specification": C_Monitored_Entity_Specification,
    "C_Monitored_Entity_run_IBIT": C_Monitored_Entity_run_IBIT,
    "C_Monitored_Characteristic": C_Monitored_Characteristic,
    "C_Monitored_Characteristic_Specification": C_Monitored_Characteristic_Specification,
    "C_Threshold": C_Threshold,
    "C_Threshold_Specification": C_Threshold_Specification,
    "C_Threshold_Exceedence_Event": C_Threshold_Exceedence_Event,
    "C_Failure_Event": C_Failure_Event,
    "C_Installed_Software": C_Installed_Software,
    "C_Preventive_Maintenance_Recommended_Event": C_Preventive_Maintenance_Recommended_Event,
}
"""Topic name -> type of every UCMS topic (the topic name is the struct name)."""

REMOTE_TOPICS: dict[str, type] = {
    "BlackBox_Log_Request": C_Log_Request,
    "BlackBox_Log_Reply": C_Log_Reply,
    "BlackBox_IBIT_Result": C_IBIT_Result,
    "BlackBox_IBIT_Request": C_IBIT_Request,
}
"""Topic name -> type of the black box's remote interface topics."""
