"""Remote log requests over DDS, answered from the recorder's health log.

A station writes a ``C_Log_Request`` addressed to a robot (``A_recipientID`` = the robot's
identifier, as in its UCMS samples) with optional entity, characteristic (exact or glob),
time range and kinds. The black box answers with numbered ``C_Log_Reply`` chunks of at most
``chunk_size`` entries (each the recorder's ``LogEntry.to_dict()`` as JSON), the last one
flagged; a request it cannot answer gets a single chunk whose status says why. The reply
carries the request id and the requesting station's id, so any number of stations can ask
at once.

Only stations the robot's configuration allows are answered: the request is signed
(:mod:`blackbox.transport.auth`) over :func:`request_fields`, and anything else gets the
single chunk ``refused: <reason>``. Every field is checked against bounds first
(:func:`check_request`): a request outside them is an error, never "no limit".

A robot with a key signs every chunk (:mod:`blackbox.transport.provenance`); a client
given the robot's public key takes only chunks with a valid signature, so a forged reply
racing the robot's is counted (``LogAnswer.forged``) and dropped, never used.
"""

from __future__ import annotations

import itertools
import json
import secrets
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from blackbox.health.ids import robot_resource_id, stable_int
from blackbox.health.types import (
    C_Log_Reply,
    C_Log_Request,
    T_DateTimeType,
    T_IdentifierType,
    datetime_of,
    seconds_of,
)
from blackbox.transport.auth import (
    AccessPolicy,
    RequestSigner,
    RequestVerifier,
    from_wire,
    to_wire,
)
from blackbox.transport.participant import HealthBus, matched_both_ways
from blackbox.transport.provenance import SampleSigner, reply_signed_by
from blackbox.transport.resend import RecentAnswers, Resend

REPLY_TOPIC = "BlackBox_Log_Reply"

DEFAULT_CHUNK = 200
MAX_ENTRIES = 1_000_000
MAX_TEXT = 256
MAX_KINDS = 16


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


def _ns(dt: T_DateTimeType) -> int:
    return int(dt.A_second) * 1_000_000_000 + int(dt.A_nanoseconds)


def request_fields(request: C_Log_Request) -> dict[str, Any]:
    """What a station's signature covers: every field of the request but the signature."""
    return {"request_id": [int(request.A_requestID.A_resourceId),
                           int(request.A_requestID.A_instanceId)],
            "recipient": [int(request.A_recipientID.A_resourceId),
                          int(request.A_recipientID.A_instanceId)],
            "time_ns": _ns(request.A_timeOfDataGeneration),
            "entity": request.A_entity, "characteristic": request.A_characteristic,
            "since_ns": _ns(request.A_since), "until_ns": _ns(request.A_until),
            "kinds": list(request.A_kinds), "max_entries": int(request.A_maxEntries)}


def check_request(request: C_Log_Request) -> str | None:
    """Why a request is out of bounds, or ``None``. Bounds keep a request from making the
    robot work without limit; ``A_maxEntries`` 0 means "all", at most :data:`MAX_ENTRIES`."""
    if not 0 <= int(request.A_maxEntries) <= MAX_ENTRIES:
        return f"A_maxEntries must be 0 (all, at most {MAX_ENTRIES:,}) or 1..{MAX_ENTRIES:,}"
    if len(request.A_entity) > MAX_TEXT or len(request.A_characteristic) > MAX_TEXT:
        return f"A_entity and A_characteristic are at most {MAX_TEXT} characters"
    if len(request.A_kinds) > MAX_KINDS:
        return f"at most {MAX_KINDS} kinds"
    for dt in (request.A_since, request.A_until):
        if dt.A_second < 0 or not 0 <= dt.A_nanoseconds < 1_000_000_000:
            return "A_since and A_until must be valid times"
    start, end = _time_or_none(request.A_since), _time_or_none(request.A_until)
    if start is not None and end is not None and start > end:
        return "A_since is after A_until"
    return None


class LogService:
    """Answers log requests addressed to one robot."""

    def __init__(self, bus: HealthBus, robot_id: str, open_source: Callable[[], LogSource],
                 chunk_size: int = DEFAULT_CHUNK, verifier: RequestVerifier | None = None,
                 signer: SampleSigner | None = None) -> None:
        self.robot = T_IdentifierType(robot_resource_id(robot_id), 0)
        self.signer = signer
        self.verifier = verifier or RequestVerifier(robot_id, AccessPolicy())
        self._open_source = open_source
        self.chunk_size = max(1, chunk_size)
        self.reader = bus.reader("BlackBox_Log_Request")
        self.writer = bus.writer("BlackBox_Log_Reply")
        self.answered = 0
        self.refused = 0
        self._recent: RecentAnswers[tuple[int, int], None] = RecentAnswers()

    def poll(self) -> int:
        """Answer every pending request; returns how many were answered."""
        count = 0
        for request in self.reader.take(N=32):
            if not isinstance(request, C_Log_Request):
                continue
            if request.A_recipientID.A_resourceId != self.robot.A_resourceId:
                continue
            key = (int(request.A_requestID.A_resourceId),
                   int(request.A_requestID.A_instanceId))
            for reply in self.replies(request):
                if self.signer is not None:
                    self.signer.seal(REPLY_TOPIC, reply)
                self.writer.write(reply)
            self._recent.answered(key, time.monotonic(), None)
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

        problem = check_request(request)
        if problem is not None:
            yield reply(0, True, f"error: {problem}", [])
            return
        verdict = self.verifier.verify("logs", request_fields(request),
                                       from_wire(request.A_signed))
        if not verdict.allowed:
            self.refused += 1
            yield reply(0, True, f"refused: {verdict.reason}", [])
            return
        key = (int(request.A_requestID.A_resourceId), int(request.A_requestID.A_instanceId))
        if self._recent.crossing(key, time.monotonic()):
            return  # the station's resend crossed our answer
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


ANSWERED_REMEMBERED = 64
"""Recent requests whose late replies are still checked for the robot's signature."""


@dataclass
class LogAnswer:
    status: str
    entries: list[dict[str, Any]]
    chunks: int
    complete: bool
    forged: int = 0
    """Replies to this request that did not carry the robot's signature (dropped)."""


class LogClient:
    """Asks robots for their logs (``blackbox request-logs``, the listener's backfill)."""

    def __init__(self, bus: HealthBus, station: str | None = None,
                 signer: RequestSigner | None = None) -> None:
        """``signer`` signs the requests; without one the key named by
        ``$BLACKBOX_STATION_KEY`` is used if set, else requests go unsigned."""
        self.signer = signer if signer is not None else RequestSigner.from_environment()
        station = station or (self.signer.station if self.signer else
                              f"station-{secrets.token_hex(4)}")
        self.station = stable_int("station", station)
        self.writer = bus.writer("BlackBox_Log_Request")
        self.reader = bus.reader("BlackBox_Log_Reply")
        self._numbers = itertools.count(secrets.randbits(20))
        self._waiter = bus.waiter([self.reader])
        self._answered: OrderedDict[tuple[int, int], tuple[str, Ed25519PublicKey]] = \
            OrderedDict()
        self._late_forged: Counter[str] = Counter()

    def _check_late(self, reply: C_Log_Reply) -> None:
        """A reply to one of our recent requests that came after its answer was complete
        (or while another request was waiting): dropped, but counted as forged for its robot
        when the robot did not sign it, so a forgery that loses the race is still seen."""
        rid = reply.A_requestID
        known = self._answered.get((int(rid.A_resourceId), int(rid.A_instanceId)))
        if known is not None and not reply_signed_by(known[1], known[0], REPLY_TOPIC, reply):
            self._late_forged[known[0]] += 1

    def take_late(self, max_replies: int = 256) -> dict[str, int]:
        """Take replies waiting between requests (replies to other stations, late chunks of
        ours) so they do not pile up in the reader; returns the forged ones among ours per
        robot, as :meth:`late_forged` does."""
        for reply in self.reader.take(N=max_replies):
            if isinstance(reply, C_Log_Reply):
                self._check_late(reply)
        return self.late_forged()

    def late_forged(self) -> dict[str, int]:
        """Forged replies to recent requests counted since the last call, per robot."""
        counts, self._late_forged = dict(self._late_forged), Counter()
        return counts

    def wait_for_robot(self, timeout: float) -> bool:
        """Wait until some black box is matched both ways (requests and replies)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if matched_both_ways(self.writer, self.reader):
                return True
            time.sleep(0.05)
        return False

    def request(self, robot_id: str, *, entity: str | None = None,
                characteristic: str | None = None, since: float | None = None,
                until: float | None = None, kinds: Iterable[str] = (),
                max_entries: int = 0, timeout: float = 10.0,
                robot_key: Ed25519PublicKey | None = None) -> LogAnswer:
        """Ask ``robot_id`` and collect its answer. With ``robot_key`` (the key a station
        enrolled for the robot) only chunks the robot signed are taken."""
        if not 0 <= max_entries <= MAX_ENTRIES:
            raise ValueError(f"max_entries must be 0 (all) or 1..{MAX_ENTRIES:,}")
        number = next(self._numbers) & 0x7FFF_FFFF
        request_id = T_IdentifierType(self.station, number)
        self.wait_for_robot(min(timeout, 5.0))

        def signed() -> C_Log_Request:
            """The request, signed anew each time it is written (a signature's nonce is
            taken once: the same bytes again would be refused as a replay)."""
            request = C_Log_Request(
                A_requestID=request_id,
                A_recipientID=T_IdentifierType(robot_resource_id(robot_id), 0),
                A_timeOfDataGeneration=datetime_of(time.time()),
                A_entity=entity or "", A_characteristic=characteristic or "",
                A_since=datetime_of(since) if since is not None else T_DateTimeType(),
                A_until=datetime_of(until) if until is not None else T_DateTimeType(),
                A_kinds=list(kinds), A_maxEntries=max_entries)
            if self.signer is not None:
                request.A_signed = to_wire(self.signer.sign("logs", robot_id,
                                                            request_fields(request)))
            return request

        self.writer.write(signed())
        chunks: dict[int, C_Log_Reply] = {}
        last: int | None = None
        forged = 0
        now = time.monotonic()
        deadline = now + timeout
        resend = Resend(now)
        while time.monotonic() < deadline:
            if not chunks and resend.due(time.monotonic()):
                self.writer.write(signed())
            for reply in self.reader.take(N=64):
                if not isinstance(reply, C_Log_Reply):
                    continue
                if reply.A_requestID != request_id:
                    self._check_late(reply)
                    continue
                if robot_key is not None and not reply_signed_by(robot_key, robot_id,
                                                                 REPLY_TOPIC, reply):
                    forged += 1
                    continue
                chunks[reply.A_chunkIndex] = reply
                if reply.A_last:
                    last = reply.A_chunkIndex
            if last is not None and all(i in chunks for i in range(last + 1)):
                break
            self._waiter.wait(0.1)
        complete = last is not None and all(i in chunks for i in range(last + 1))
        if robot_key is not None:
            self._answered[(self.station, number)] = (robot_id, robot_key)
            while len(self._answered) > ANSWERED_REMEMBERED:
                self._answered.popitem(last=False)
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
        return LogAnswer(status, entries, len(chunks), complete, forged)
