"""The thesis's proposed UCMS additions (section 6.2.3) as a separate extension.

UCMS cannot say what the black box knows about a characteristic beyond unit and descriptor,
nor whether a threshold was crossed because the robot changed state or because something
broke, nor which name an entity has. Rather than altering the NGVA types (which would break
every plain UCMS reader), the additions travel on their own topics, keyed by the *same*
source ids as the UCMS samples they extend. A plain UCMS reader never subscribes to them;
a black-box-aware station joins them by id.

No ``from __future__ import annotations`` here: the IDL machinery needs real annotations.
"""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlEnum, IdlStruct
from cyclonedds.idl.annotations import key
from cyclonedds.idl.types import int32, int64, sequence, uint8, uint64

from blackbox.health.types import T_DateTimeType, T_IdentifierType


class T_EventKind(IdlEnum, typename="P_BlackBox_Ext.T_EventKind"):
    """What an event is: a threshold crossed by a fault or by a change between healthy
    states, a component diagnosed faulty (``FAILURE``, extends a ``C_Failure_Event``), or a
    component no longer diagnosed faulty (``RECTIFICATION``, an event of its own: UCMS has no
    type for it)."""

    L_EventKind_FAULT = 0
    L_EventKind_STATE_CHANGE = 1
    L_EventKind_FAILURE = 2
    L_EventKind_RECTIFICATION = 3


@dataclass
class C_Parameter(IdlStruct, typename="P_BlackBox_Ext.C_Parameter"):
    A_name: str = ""
    A_value: float = 0.0


@dataclass
class C_Entity_Description(IdlStruct, typename="P_BlackBox_Ext.C_Entity_Description"):
    """Names a Monitored Entity: the robot (``A_kind`` ``robot``), a node, a topic, ..."""

    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_robotId: str = ""
    A_name: str = ""
    A_kind: str = ""
    A_parent_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Characteristic_Extension(IdlStruct, typename="P_BlackBox_Ext.C_Characteristic_Extension"):
    """What a Monitored Characteristic measures and how it is filtered and logged.

    ``A_expectedNoise`` is the standard deviation the configuration expects of the
    filtered value (NaN when not known); ``A_periodicLoggingIntervalInSeconds`` is how often
    the recorder stores it periodically (0 when not periodically logged);
    ``A_evaluationIntervalInSeconds`` is the exact observer interval (UCMS's publishing
    interval is whole seconds).
    """

    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_robotId: str = ""
    A_name: str = ""
    A_observer: str = ""
    A_resource: str = ""
    A_quantity: str = ""
    A_expectedNoise: float = float("nan")
    A_filterType: str = ""
    A_filterParameters: sequence[C_Parameter] = field(default_factory=list)
    A_periodicLoggingIntervalInSeconds: float = 0.0
    A_evaluationIntervalInSeconds: float = 0.0
    A_states: sequence[str] = field(default_factory=list)


@dataclass
class C_Event_Extension(IdlStruct, typename="P_BlackBox_Ext.C_Event_Extension"):
    """Every event's identity and kind.

    Keyed by the ``A_sourceID`` of the UCMS event it extends (a Threshold Exceedence Event:
    fault or state change; a Failure Event), or, for a rectification, its own id with the
    recovered entity in ``A_entity_sourceID``. ``A_eventId`` is ``<boot>-<sequence>``
    (``blackbox.health.identity``): unique per robot, and without holes per boot, so a
    station deduplicates by it and notices what it missed.
    """

    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_timeOfDataGeneration: T_DateTimeType = field(default_factory=T_DateTimeType)
    A_kind: T_EventKind = T_EventKind.L_EventKind_FAULT
    A_code: int32 = 0
    A_codeName: str = ""
    A_fromStates: sequence[str] = field(default_factory=list)
    A_toStates: sequence[str] = field(default_factory=list)
    A_message: str = ""
    A_eventId: str = ""
    A_entity_sourceID: T_IdentifierType = field(default_factory=T_IdentifierType)


@dataclass
class C_Sample_Signature(IdlStruct, typename="P_BlackBox_Ext.C_Sample_Signature"):
    """The robot's Ed25519 signature of one sample it published (``blackbox.transport.
    provenance``), keyed like the sample: by its topic and ``A_sourceID``.

    ``A_digest`` is SHA-256 of the sample's CDR encoding; ``A_boot`` and ``A_counter`` (1, 2,
    ... per boot) and ``A_signedNs`` (the robot's clock) order the signatures, so a station
    refuses an older signed state replayed over a newer one. ``A_publicKey`` (32 raw bytes)
    says which key signed, so a station can offer it for enrolment (trust on first use).
    """

    A_sourceID: T_IdentifierType
    key("A_sourceID")
    A_topic: str = ""
    key("A_topic")
    A_robotId: str = ""
    A_boot: str = ""
    A_counter: uint64 = 0
    A_signedNs: int64 = 0
    A_digest: sequence[uint8] = field(default_factory=list)
    A_publicKey: sequence[uint8] = field(default_factory=list)
    A_signature: sequence[uint8] = field(default_factory=list)


EXTENSION_TOPICS: dict[str, type] = {
    "BlackBox_Entity_Description": C_Entity_Description,
    "BlackBox_Characteristic_Extension": C_Characteristic_Extension,
    "BlackBox_Event_Extension": C_Event_Extension,
    "BlackBox_Sample_Signature": C_Sample_Signature,
}
"""Topic name -> type of the extension topics."""
