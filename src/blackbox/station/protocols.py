"""What the station asks of its database, as small protocols.

The follower only writes (:class:`FleetWrites`, :class:`RequestRecords`), the web pages and
the API only read (:class:`FleetReads`, :class:`EventReads`, :class:`LogReads`) and listen
(:class:`ChangeSource`, :class:`ProblemSource`). :class:`StationDatabase` is all of them: what
a storage backend implements. :class:`blackbox.station.store.StationStore` implements it on
SQLite (the embedded default) and on PostgreSQL (several station processes, one database);
``tests/test_station_store_contract.py`` holds every backend to the same behaviour.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import IO, Any, Protocol

from blackbox.record.store import LogEntry
from blackbox.station.changes import Change, Subscription
from blackbox.station.records import (
    MAX_PAGE,
    Characteristic,
    Diagnosis,
    EntityNode,
    Event,
    EventPage,
    IbitRun,
    LogRequest,
    Point,
    Problem,
    RobotRef,
    RobotSummary,
)
from blackbox.station.status_history import StatusTrack
from blackbox.station.writequeue import FlushTimes


class FleetWrites(Protocol):
    """The follower's queued writes of what robots say; committed by :meth:`flush`."""

    def heard(self, resource_id: int, at: float) -> None: ...

    def put_robot_id(self, resource_id: int, robot_id: str) -> None: ...

    def put_entity(self, resource_id: int, instance_id: int, *, name: str | None = None,
                   kind: str | None = None, parent: int | None = None,
                   status: str | None = None, online: bool | None = None,
                   bit: bool | None = None, failures: int | None = None,
                   characteristics: Sequence[int] | None = None,
                   cause: str | None = None, actions: str | None = None,
                   updated: float | None = None) -> None: ...

    def put_robot_online(self, resource_id: int, online: bool) -> None: ...

    def put_diagnosis(self, resource_id: int, components: Sequence[str],
                      since: float | None) -> None: ...

    def put_characteristic(self, resource_id: int, instance_id: int, *,
                           entity: int | None = None, name: str | None = None,
                           observer: str | None = None, resource: str | None = None,
                           quantity: str | None = None, unit: str | None = None,
                           expected_noise: float | None = None,
                           exceeded: bool | None = None) -> None: ...

    def put_value(self, resource_id: int, instance_id: int, t: float, value: float,
                  entity: int | None = None) -> None: ...

    def put_threshold(self, resource_id: int, instance_id: int, characteristic: int,
                      name: str, type_: str, value: float) -> None: ...

    def add_event(self, resource_id: int, t: float, kind: str, *, dedup: str,
                  entity: str = "", characteristic: str = "", text: str = "",
                  origin: str = "live", details: dict[str, Any] | None = None,
                  refers_to: int | None = None) -> None: ...

    def name_event(self, resource_id: int, unnamed: str, t: float, kind: str, *, dedup: str,
                   entity: str = "", characteristic: str = "", text: str = "",
                   origin: str = "live", details: dict[str, Any] | None = None,
                   rewrite: bool = True) -> None: ...

    def name_entity_events(self, resource_id: int, placeholder: str, name: str,
                           texts: Mapping[str, str]) -> None: ...

    def flush(self, force: bool = False) -> bool: ...

    def start_writer(self) -> None: ...

    def flush_soon(self) -> None: ...

    def stop_writer(self) -> None: ...

    @property
    def pending(self) -> int: ...

    @property
    def dropped_points(self) -> int: ...

    @property
    def coalesced_points(self) -> int: ...

    @property
    def flush_times(self) -> FlushTimes: ...

    @property
    def dropped_changes(self) -> int: ...


class RequestRecords(Protocol):
    """Operators' requests (acknowledgements, log requests, IBIT) and their progress."""

    def acknowledge(self, event_id: int, user: str, note: str = "") -> Event: ...

    def create_log_request(self, resource_id: int, robot_id: str, *, entity: str | None,
                           characteristic: str | None, since: float | None,
                           until: float | None, kinds: Sequence[str],
                           requested_by: str) -> int: ...

    def add_log_rows(self, request: int, first_seq: int,
                     entries: Sequence[LogEntry]) -> None: ...

    def update_log_request(self, request: int, resource_id: int, *, status: str,
                           rows: int, pages: int, progress: float, message: str = "",
                           finished: float | None = None) -> None: ...

    def create_ibit_run(self, resource_id: int, robot_id: str, entity: str,
                        requested_by: str) -> int: ...

    def finish_ibit_run(self, run: int, resource_id: int, *, status: str,
                        health: str | None, observations: int, failed: int,
                        report: Sequence[str]) -> None: ...


class FleetReads(Protocol):
    """Robots, their entities, diagnosis and characteristics, as the pages show them."""

    stale_after: float

    def resource_of(self, robot: RobotRef) -> int: ...

    def robot_id_of(self, resource_id: int) -> str: ...

    def last_event_time(self, robot: RobotRef) -> float | None: ...

    def last_heard(self, robot: RobotRef) -> float | None: ...

    def heard_times(self) -> list[tuple[int, str, float | None]]: ...

    def fleet(self, now: float | None = None) -> list[RobotSummary]: ...

    def robot(self, robot: RobotRef, now: float | None = None) -> RobotSummary: ...

    def entities(self, robot: RobotRef, now: float | None = None) -> list[EntityNode]: ...

    def entity(self, robot: RobotRef, instance_id: int) -> EntityNode | None: ...

    def entity_by_name(self, robot: RobotRef, name: str) -> EntityNode | None: ...

    def status_track(self, robot: RobotRef, since: float, until: float) -> StatusTrack: ...

    def diagnosis(self, robot: RobotRef) -> Diagnosis: ...

    def characteristics(self, robot: RobotRef,
                        entity: int | None = None) -> list[Characteristic]: ...

    def series(self, robot: RobotRef, characteristic: int, since: float | None = None,
               until: float | None = None, max_points: int = 2000) -> list[Point]: ...


class EventReads(Protocol):
    """The event timeline."""

    def event(self, event_id: int) -> Event | None: ...

    def events(self, robot: RobotRef | None = None, *, entity: str | None = None,
               kinds: Iterable[str] | None = None, since: float | None = None,
               until: float | None = None, unacknowledged: bool = False,
               cursor: str | None = None, limit: int = 100) -> EventPage: ...

    def events_after(self, after_id: int, limit: int = 500) -> list[Event]: ...

    def last_event_id(self) -> int: ...

    def count_events(self, robot: RobotRef | None = None,
                     kinds: Iterable[str] | None = None,
                     origin: str | None = None) -> int: ...


class LogReads(Protocol):
    """Log requests with the rows robots sent, and built-in test runs."""

    def log_request(self, request: int) -> LogRequest | None: ...

    def log_requests(self, robot: RobotRef | None = None,
                     limit: int = 50) -> list[LogRequest]: ...

    def log_entries(self, request: int, offset: int = 0,
                    limit: int = MAX_PAGE) -> list[LogEntry]: ...

    def iter_log_entries(self, request: int, batch: int = MAX_PAGE) -> Iterator[LogEntry]: ...

    def export_log(self, request: int, fmt: str, out: IO[Any]) -> int: ...

    def ibit_run(self, run: int) -> IbitRun | None: ...

    def ibit_runs(self, robot: RobotRef | None = None, limit: int = 50) -> list[IbitRun]: ...


class ChangeSource(Protocol):
    """What changed after each committed flush (Server-Sent Events without polling)."""

    @property
    def sequence(self) -> int: ...

    def wait_for_change(self, after: int, timeout: float) -> int: ...

    def subscribe(self, maxsize: int = 256) -> Subscription: ...

    def add_listener(self, callback: Callable[[Change], None]) -> Callable[[], None]: ...


class ProblemSource(Protocol):
    """Problems for operators: what the station could not do."""

    def report_problem(self, source: str, message: str) -> None: ...

    def problems(self, limit: int = 50) -> list[Problem]: ...

    def clear_problem(self, source: str) -> None: ...


class StationDatabase(FleetWrites, RequestRecords, FleetReads, EventReads, LogReads,
                      ChangeSource, ProblemSource, Protocol):
    """Everything the station keeps: what a storage backend implements."""

    path: str

    def close(self) -> None: ...
