"""The robots a station trusts: one Ed25519 public key per robot id.

A station shows a robot's health as authenticated only when it knows the robot's key.
Keys come three ways, all ending in the ``trusted_robots`` table of the station's
database (beside the store's tables, like the accounts):

* ``blackbox station robots enrol ROBOT_ID --key ROBOT.key.pub`` (the file ``blackbox
  keygen`` wrote on the robot);
* ``blackbox station --robots FILE``: a file of ``.pub`` lines, ``ed25519 <base64>
  <robot id>`` (the robots' ``.pub`` files concatenated), enrolled at start;
* trust on first use: the station notes the key each robot's signatures carry
  (``seen_robot_keys``) and an administrator confirms it (CLI ``robots enrol ROBOT_ID
  --seen`` or the robot page), never automatically.

A robot that is not enrolled is followed as before, its data marked unauthenticated.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from blackbox.errors import BlackBoxError
from blackbox.health.ids import robot_resource_id
from blackbox.station import schema
from blackbox.station.database import (
    Database,
    DatabaseError,
    ReconnectingConnection,
    open_database,
)
from blackbox.transport.auth import RequestAuthError, parse_public_key, public_key_text

MAX_ROBOT_ID = 200
MAX_SEEN_PER_ROBOT = 8
SEEN_UPDATE = 30.0


class EnrolmentError(BlackBoxError):
    """A key or a robots file cannot be used; the message says where and why."""


@dataclass(frozen=True, slots=True)
class TrustedRobot:
    robot_id: str
    public_key: str
    """base64 of the 32 raw bytes."""
    source: str
    """``cli``, ``file``, ``confirmed`` (trust on first use) or ``api``."""
    enrolled: float

    @property
    def key(self) -> Ed25519PublicKey:
        return parse_public_key(self.public_key)


@dataclass(frozen=True, slots=True)
class SeenKey:
    robot_id: str
    public_key: str
    first_seen: float
    last_seen: float


def read_robots_file(path: Path) -> list[tuple[str, str]]:
    """``(robot id, base64 key)`` of every line ``ed25519 <base64> <robot id>``; blank
    lines and ``#`` comments are skipped. A bad line raises :class:`EnrolmentError`
    naming the file and line."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise EnrolmentError(f"{path}: cannot read: {getattr(exc, 'strerror', exc)}") from None
    out: list[tuple[str, str]] = []
    for number, line in enumerate(lines, 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.split()
        if len(parts) != 3 or parts[0] != "ed25519":
            raise EnrolmentError(f"{path}:{number}: expected 'ed25519 <base64 key> <robot id>'")
        try:
            key = public_key_text(parse_public_key(parts[1]))
        except RequestAuthError as exc:
            raise EnrolmentError(f"{path}:{number}: {exc}") from None
        if any(robot == parts[2] for robot, _ in out):
            raise EnrolmentError(f"{path}:{number}: robot {parts[2]!r} is listed twice")
        out.append((_robot_id(parts[2], f"{path}:{number}"), key))
    return out


def read_public_key_file(path: Path) -> str:
    """The base64 key of a ``.pub`` file (or a bare base64 key)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise EnrolmentError(f"{path}: cannot read: {getattr(exc, 'strerror', exc)}") from None
    try:
        return public_key_text(parse_public_key(text))
    except RequestAuthError as exc:
        raise EnrolmentError(f"{path}: {exc}") from None


def _robot_id(robot_id: str, where: str = "robot id") -> str:
    if not robot_id or len(robot_id) > MAX_ROBOT_ID or not robot_id.isprintable():
        raise EnrolmentError(f"{where}: a robot id is 1..{MAX_ROBOT_ID} printable characters")
    return robot_id


class RobotKeys:
    """The trusted robots of the station database at ``path`` (``":memory:"``: kept in a
    private in-memory database, for ``blackbox listen`` and tests).

    Thread-safe. :meth:`by_resource` is what the follower asks per sample; it is cached
    and re-read from the file at most every :attr:`refresh` seconds, so a robot enrolled
    from the command line while the station runs is picked up without a restart.
    """

    refresh = 2.0

    def __init__(self, path: str | Path | Database,
                 clock: Callable[[], float] = time.time) -> None:
        self.database = open_database(path)
        self.path = self.database.describe()
        self.clock = clock
        self._lock = threading.Lock()
        try:
            self._db = ReconnectingConnection(self.database)
            schema.ensure_part(self.database, self._db, "robot_keys")
        except DatabaseError as exc:
            raise EnrolmentError(f"{self.path}: cannot keep trusted robots: {exc}") from None
        self._cache: dict[int, tuple[str, Ed25519PublicKey]] = {}
        self._cached_at = -float("inf")
        self._noted: dict[tuple[str, str], float] = {}

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def enrol(self, robot_id: str, public_key: str, source: str = "cli") -> TrustedRobot:
        """Trust ``public_key`` (base64 or a ``.pub`` line) for ``robot_id``, replacing an
        earlier key of that robot."""
        robot_id = _robot_id(robot_id)
        try:
            key = public_key_text(parse_public_key(public_key))
        except RequestAuthError as exc:
            raise EnrolmentError(str(exc)) from None
        now = self.clock()
        with self._lock:
            self._db.execute("INSERT INTO trusted_robots VALUES (?, ?, ?, ?) ON CONFLICT "
                             "(robot_id) DO UPDATE SET public_key = excluded.public_key, "
                             "source = excluded.source, enrolled = excluded.enrolled",
                             (robot_id, key, source, now))
            self._cached_at = -float("inf")
        return TrustedRobot(robot_id, key, source, now)

    def confirm_seen(self, robot_id: str) -> TrustedRobot:
        """Trust on first use, confirmed: enrol the one key this robot's signatures carried.
        Refused when none or several were seen (a second writer: an administrator must
        enrol the right key from its file)."""
        seen = [k for k in self.seen() if k.robot_id == robot_id]
        if not seen:
            raise EnrolmentError(f"no signed sample of robot {robot_id!r} seen yet")
        if len({k.public_key for k in seen}) > 1:
            raise EnrolmentError(f"robot {robot_id!r} was seen with {len(seen)} different "
                                 "keys; enrol the right one with --key")
        return self.enrol(robot_id, seen[0].public_key, "confirmed")

    def remove(self, robot_id: str) -> bool:
        with self._lock:
            gone = self._db.execute("DELETE FROM trusted_robots WHERE robot_id = ?",
                                    (robot_id,)).rowcount
            self._cached_at = -float("inf")
        return bool(gone)

    def robots(self) -> list[TrustedRobot]:
        with self._lock:
            rows = self._db.execute("SELECT robot_id, public_key, source, enrolled FROM "
                                    "trusted_robots ORDER BY robot_id").fetchall()
        return [TrustedRobot(*r) for r in rows]

    def trusted(self, robot_id: str) -> TrustedRobot | None:
        return next((r for r in self.robots() if r.robot_id == robot_id), None)

    def note_seen(self, robot_id: str, public_key: Ed25519PublicKey) -> None:
        """Remember that signatures of ``robot_id`` carried ``public_key`` (at most
        :data:`MAX_SEEN_PER_ROBOT` keys per robot; a flood cannot grow the table much)."""
        key = public_key_text(public_key)
        now = self.clock()
        last = self._noted.get((robot_id, key))
        if last is not None and now - last < SEEN_UPDATE:
            return  # one write per key and robot every SEEN_UPDATE seconds at most
        # the database may be away (the store reports that): the key is noted again later
        with contextlib.suppress(DatabaseError):
            self._note_seen(robot_id, key, now, last)

    def _note_seen(self, robot_id: str, key: str, now: float, last: float | None) -> None:
        with self._lock:
            if last is None:
                count = self._db.execute("SELECT COUNT(*) FROM seen_robot_keys WHERE "
                                         "robot_id = ?", (robot_id,)).fetchone()[0]
                if count >= MAX_SEEN_PER_ROBOT or len(robot_id) > MAX_ROBOT_ID:
                    return
                self._db.execute("INSERT INTO seen_robot_keys VALUES (?, ?, ?, ?) "
                                 "ON CONFLICT DO NOTHING", (robot_id, key, now, now))
            self._noted[(robot_id, key)] = now
            self._db.execute("UPDATE seen_robot_keys SET last_seen = ? WHERE robot_id = ? "
                             "AND public_key = ?", (now, robot_id, key))

    def seen(self) -> list[SeenKey]:
        with self._lock:
            rows = self._db.execute("SELECT robot_id, public_key, first_seen, last_seen FROM "
                                    "seen_robot_keys ORDER BY robot_id, first_seen").fetchall()
        return [SeenKey(*r) for r in rows]

    def by_resource(self) -> dict[int, tuple[str, Ed25519PublicKey]]:
        """Resource id -> (robot id, key) of every trusted robot (cached; while the database
        is away the last list read stays in force)."""
        now = time.monotonic()
        if now - self._cached_at >= self.refresh:
            try:
                robots = self.robots()
            except DatabaseError:
                self._cached_at = now
                return self._cache
            fresh = {robot_resource_id(r.robot_id): (r.robot_id, r.key) for r in robots}
            self._cache, self._cached_at = fresh, now
        return self._cache
