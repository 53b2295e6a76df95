"""Remote log requests over DDS, answered from the recorder's health log.

A station writes a ``C_Log_Request`` addressed to a robot (``A_recipientID`` = the robot's
identifier, as in its UCMS samples) with optional entity, characteristic (exact or glob),
time range and kinds. The black box answers with numbered ``C_Log_Reply`` chunks of at most
``chunk_size`` entries (each the recorder's ``LogEntry.to_dict()`` as JSON), the last one
flagged; a request it cannot answer gets a single chunk whose status says why. The reply
carries the request id and the requesting station's id, so any number of stations can ask
at once.
"""

from __future__ import annotations

import itertools
import json
import secrets
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.util import duration

from blackbox.health.ids import robot_resource_id, stable_int
from blackbox.health.types import (
    C_Log_Reply,
    C_Log_Request,
    T_DateTimeType,
    T_IdentifierType,
    datetime_of,
    seconds_of,
)
from blackbox.transport.participant import Bus

DEFAULT_CHUNK = 200
MAX_ENTRIES = 1_000_000


class LogEntryLike(Protocol):
    def to_dict(self) -> dict[str, Any]: ...


class LogSource(Protocol):
    """What the log service needs from the recorder (``blackbox.record.Store``)."""

    def query(self, entity: str | None = None, characteristic: str | None = None,
              start: float | None = None, end: float | None = None,
              kinds: Sequence[str] | None = None,
              limit: int | None = None) -> Iterator[LogEntryLike]: ...


def open_store(path: str) -> LogSource:
    """The recorder's store at ``path``, read-only."""
    from blackbox.record import Store

    return Store.open(path, readonly=True, check=False)


def _time_or_none(dt: T_DateTimeType) -> float | None:
    return None if dt.A_second == 0 and dt.A_nanoseconds == 0 else seconds_of(dt)


class LogService:
    """Answers log requests addressed to one robot."""

    def __init__(self, bus: Bus, robot_id: str, open_source: Callable[[], LogSource],
                 chunk_size: int = DEFAULT_CHUNK) -> None:
        self.robot = T_IdentifierType(robot_resource_id(robot_id), 0)
        self._open_source = open_source
        self.chunk_size = max(1, chunk_size)
        self.reader = bus.reader("BlackBox_Log_Request")
        self.writer = bus.writer("BlackBox_Log_Reply")
        self.answered = 0

    def poll(self) -> int:
        """Answer every pending request; returns how many were answered."""
        count = 0
        for request in self.reader.take(N=32):
            if not isinstance(request, C_Log_Request):
                continue
            if request.A_recipientID.A_resourceId != self.robot.A_resourceId:
                continue
            for reply in self.replies(request):
                self.writer.write(reply)
            count += 1
        self.answered += count
        return count

    def replies(self, request: C_Log_Request) -> Iterator[C_Log_Reply]:
        def reply(index: int, last: bool, status: str, entries: list[str]) -> C_Log_Reply:
            return C_Log_Reply(A_requestID=request.A_requestID, A_chunkIndex=index,
                               A_recipientID=T_IdentifierType(
                                   request.A_requestID.A_resourceId, 0),
                               A_sourceID=self.robot, A_timeOfDataGeneration=datetime_of(
                                   time.time()),
                               A_last=last, A_status=status, A_entries=entries)

        start, end = _time_or_none(request.A_since), _time_or_none(request.A_until)
        limit = request.A_maxEntries or MAX_ENTRIES
        try:
            source = self._open_source()
            rows = source.query(entity=request.A_entity or None,
                                characteristic=request.A_characteristic or None,
                                start=start, end=end, kinds=list(request.A_kinds) or None,
                                limit=min(limit, MAX_ENTRIES))
            pending: list[str] = []
            index = 0
            for entry in rows:
                pending.append(json.dumps(entry.to_dict(), default=str, allow_nan=True))
                if len(pending) == self.chunk_size:
                    yield reply(index, False, "ok", pending)
                    index += 1
                    pending = []
            yield reply(index, True, "ok", pending)  # possibly empty: it carries A_last
        except Exception as exc:  # the robot must never crash on a station's request
            yield reply(0, True, f"error: {exc}", [])


@dataclass
class LogAnswer:
    status: str
    entries: list[dict[str, Any]]
    chunks: int
    complete: bool


class LogClient:
    """Asks robots for their logs (``blackbox request-logs``, the listener's backfill)."""

    def __init__(self, bus: Bus, station: str | None = None) -> None:
        station = station or f"station-{secrets.token_hex(4)}"
        self.station = stable_int("station", station)
        self.writer = bus.writer("BlackBox_Log_Request")
        self.reader = bus.reader("BlackBox_Log_Reply")
        self._numbers = itertools.count(secrets.randbits(20))
        self._waitset = WaitSet(bus.participant)
        self._waitset.attach(ReadCondition(self.reader, SampleState.Any | ViewState.Any
                                           | InstanceState.Any))

    def wait_for_robot(self, timeout: float) -> bool:
        """Wait until some black box's request reader is matched."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.writer.get_matched_subscriptions():
                return True
            time.sleep(0.05)
        return False

    def request(self, robot_id: str, *, entity: str | None = None,
                characteristic: str | None = None, since: float | None = None,
                until: float | None = None, kinds: Iterable[str] = (),
                max_entries: int = 0, timeout: float = 10.0) -> LogAnswer:
        number = next(self._numbers) & 0x7FFF_FFFF
        request_id = T_IdentifierType(self.station, number)
        self.wait_for_robot(min(timeout, 5.0))
        self.writer.write(C_Log_Request(
            A_requestID=request_id,
            A_recipientID=T_IdentifierType(robot_resource_id(robot_id), 0),
            A_timeOfDataGeneration=datetime_of(time.time()),
            A_entity=entity or "", A_characteristic=characteristic or "",
            A_since=datetime_of(since) if since is not None else T_DateTimeType(),
            A_until=datetime_of(until) if until is not None else T_DateTimeType(),
            A_kinds=list(kinds), A_maxEntries=max_entries))
        chunks: dict[int, C_Log_Reply] = {}
        last: int | None = None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for reply in self.reader.take(N=64):
                if not isinstance(reply, C_Log_Reply) or reply.A_requestID != request_id:
                    continue
                chunks[reply.A_chunkIndex] = reply
                if reply.A_last:
                    last = reply.A_chunkIndex
            if last is not None and all(i in chunks for i in range(last + 1)):
                break
            self._waitset.wait(duration(milliseconds=100))
        complete = last is not None and all(i in chunks for i in range(last + 1))
        entries: list[dict[str, Any]] = []
        status = "timeout: no complete answer" if not complete else "ok"
        for i in sorted(chunks):
            reply = chunks[i]
            if reply.A_status != "ok":
                status = reply.A_status
            for text in reply.A_entries:
                try:
                    item = json.loads(text)
                except ValueError:
                    continue
                if isinstance(item, dict):
                    entries.append(item)
        return LogAnswer(status, entries, len(chunks), complete)
