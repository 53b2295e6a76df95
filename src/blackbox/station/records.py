"""What the station's database holds, as the readers see it: rows as frozen dataclasses,
the vocabularies (statuses, event kinds, origins), limits and how robots are addressed.

Kept apart from any engine so the web pages, the API, the alert engine and every storage
backend share one definition of a robot summary, an event or a log request.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from blackbox.errors import BlackBoxError
from blackbox.health.ids import robot_resource_id
from blackbox.station.database import StationStoreError as StationStoreError  # re-export

STATUSES = ("OPERATIONAL", "DEGRADED", "NOT_OPERATIONAL", "UNKNOWN")
"""UCMS health statuses, in the order of their enum values."""


EVENT_KINDS = ("failure", "rectification", "diagnosis", "exceedance", "state_change",
               "acknowledgement", "ibit", "log_request")
"""Kinds of events in the timeline.

``failure``: a diagnosis named an entity faulty (UCMS Failure Event); ``rectification``:
that entity is no longer named; ``diagnosis``: the robot's set of diagnosed entities
changed (text = the explanation in plain words); ``exceedance``: a characteristic crossed a
threshold because of a fault (UCMS Threshold Exceedance Event); ``state_change``: the same
event caused by a change between healthy states (the thesis's extension);
``acknowledgement``: an operator acknowledged an event; ``ibit``: a built-in test result;
``log_request``: an operator asked a robot for its log.
"""

ORIGINS = ("live", "log", "station")
"""Where an event came from: a DDS sample, a log request (backfill), the station itself."""

DEFAULT_STALE_AFTER = 10.0
DEFAULT_SERIES_RETENTION = 1800.0
MAX_PAGE = 1000
MAX_SERIES_POINTS = 5000
MAX_PENDING = 200_000
MAX_TEXT = 2000
MAX_NAME = 200

RobotRef = int | str
"""A robot: its robot id (``"thesis-robot"``), or its UCMS resource id (``123`` or ``"#123"``)."""


class UnknownRobot(BlackBoxError, LookupError):
    """No robot with this reference has been heard of."""


@dataclass(frozen=True, slots=True)
class RobotSummary:
    """One line of the fleet page.

    ``status`` is what the operator should see: the UCMS rule over the robot's entities
    (:func:`blackbox.station.status.robot_status`), or ``UNKNOWN`` when the robot is
    ``stale`` (silent for longer than ``stale_after``) or ``offline`` (its black box said
    it stopped). ``reported_status`` is the robot entity's own UCMS status as last received.
    """

    resource_id: int
    robot_id: str
    name: str
    status: str
    reported_status: str
    last_heard: float | None
    stale: bool
    online: bool
    entities: int
    failing: int
    unacknowledged: int
    diagnosis: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class EntityNode:
    """One monitored entity: the robot itself (kind ``robot``), a node, a topic, or
    hardware (kind ``interface``). ``parent`` is the instance id of the parent entity
    (``None`` for the robot). ``status`` is ``UNKNOWN`` while the robot is stale;
    ``reported_status`` is what the black box last said."""

    instance_id: int
    name: str
    kind: str
    status: str
    reported_status: str
    online: bool
    bit_in_progress: bool
    parent: int | None
    failures: int
    updated: float | None
    characteristics: int


@dataclass(frozen=True, slots=True)
class Threshold:
    name: str
    type: str  # "min" or "max"
    value: float


@dataclass(frozen=True, slots=True)
class Characteristic:
    """A monitored characteristic with its latest value (``None`` before the first)."""

    instance_id: int
    entity: int | None
    entity_name: str
    name: str
    observer: str
    resource: str
    quantity: str
    unit: str
    value: float | None
    time: float | None
    expected_noise: float | None
    thresholds: tuple[Threshold, ...]
    exceeded: bool


@dataclass(frozen=True, slots=True)
class Point:
    time: float
    value: float


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """The robot's current diagnosis: the entities named faulty, and why, in plain words."""

    robot_id: str
    components: tuple[str, ...]
    explanation: str
    since: float | None
    causes: dict[str, str]
    actions: dict[str, str]


@dataclass(frozen=True, slots=True)
class Event:
    id: int
    resource_id: int
    robot_id: str
    time: float
    kind: str
    entity: str
    characteristic: str
    text: str
    origin: str
    acknowledged_by: str | None
    acknowledged_at: float | None
    refers_to: int | None
    details: dict[str, Any]


@dataclass(frozen=True, slots=True)
class EventPage:
    """Events newest first; pass ``next_cursor`` back as ``cursor`` for the next page
    (``None``: this was the last page)."""

    events: tuple[Event, ...]
    next_cursor: str | None


@dataclass(frozen=True, slots=True)
class Problem:
    """Something the station could not do or would not accept; shown to operators."""

    source: str
    message: str
    first: float
    last: float
    count: int


@dataclass(frozen=True, slots=True)
class LogRequest:
    """A request for a robot's log and how far it got.

    ``status``: ``pending``, ``running``, ``done``, ``error``, ``timeout`` or ``truncated``
    (stopped at ``max_rows``). ``progress`` is 0..1 (time covered of the range asked for).
    """

    id: int
    resource_id: int
    robot_id: str
    entity: str | None
    characteristic: str | None
    since: float | None
    until: float | None
    kinds: tuple[str, ...]
    requested_by: str
    created: float
    finished: float | None
    status: str
    message: str
    rows: int
    pages: int
    progress: float


@dataclass(frozen=True, slots=True)
class IbitRun:
    """A built-in test asked of a robot; ``status`` ``pending``, ``done`` or ``timeout``."""

    id: int
    resource_id: int
    robot_id: str
    entity: str
    requested_by: str
    created: float
    finished: float | None
    status: str
    health: str | None
    observations: int
    failed: int
    report: tuple[str, ...]


def clip(text: object, limit: int = MAX_TEXT) -> str:
    s = str(text)
    return s if len(s) <= limit else s[: limit - 1] + "…"


def finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def loads(text: str, default: Any) -> Any:
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        return default


def robot_resource(robot: RobotRef) -> int:
    """The UCMS resource id of a :data:`RobotRef` (the robot id's hash, see health/ids)."""
    if isinstance(robot, int):
        return robot
    if robot.startswith("#") and robot[1:].isdigit():
        return int(robot[1:])
    return robot_resource_id(robot)
