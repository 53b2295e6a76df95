"""Who may use the station: users, roles, sessions, CSRF tokens, log-in throttling, audit.

A control room's station shows a fleet's health and can make robots do things (run a
built-in test, send their logs), so it is treated as a security boundary:

* passwords are stored only as argon2id hashes (``argon2-cffi``); there is no default
  account, the first one is made with ``blackbox station user add``;
* a session is a random token kept by the browser in an HttpOnly, SameSite=Strict cookie;
  the database keeps only its SHA-256, so a stolen database opens no session. Sessions end
  on log-out, after :attr:`AuthPolicy.idle_timeout` without a request, and after
  :attr:`AuthPolicy.max_age` in any case;
* every session carries a CSRF token that each state-changing request must echo;
* failed log-ins are counted per (user name, client address); past
  :attr:`AuthPolicy.free_failures` each further attempt from that address for that name
  must wait twice as long as the last (capped at :attr:`AuthPolicy.max_backoff`, forgotten
  after :attr:`AuthPolicy.failure_window`), and answers "try again in N s". Someone
  guessing from one address thus never locks the real user out at another, nor every user
  of a shared console out at once;
* passwords follow :mod:`blackbox.station.passwords`, and the last admin can be neither
  demoted nor removed;
* every state-changing action, refused ones included, is a row of the ``web_audit`` table.

Tables live in the station's database next to the fleet data, under their own names
(``web_users``, ``web_sessions``, ``web_login_failures``, ``web_audit``; part of the one
versioned schema, :mod:`blackbox.station.schema`), so every station process on one
PostgreSQL shares the accounts and sessions. Open the
:class:`~blackbox.station.store.StationStore` on the database first: it refuses a file that
already has tables but not its own.
"""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError, VerifyMismatchError

from blackbox.errors import BlackBoxError
from blackbox.station import schema
from blackbox.station.database import (
    Database,
    DuplicateRow,
    ReconnectingConnection,
    open_database,
)
from blackbox.station.passwords import password_problem


class Role(IntEnum):
    """What a user may do; each role may do everything the roles below it may."""

    VIEWER = 1
    OPERATOR = 2
    ADMIN = 3

    @classmethod
    def parse(cls, text: str) -> Role:
        try:
            return cls[text.strip().upper()]
        except KeyError:
            raise ValueError(f"unknown role {text!r}: expected viewer, operator or admin") from None

    @property
    def label(self) -> str:
        return self.name.lower()


USER_NAME = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")


class StationAuthError(BlackBoxError):
    """A log-in or account change the station refuses; the message is safe to show to the
    user."""




@dataclass(frozen=True, slots=True)
class AuthPolicy:
    idle_timeout: float = 30 * 60.0
    """Seconds without a request after which a session ends."""
    max_age: float = 12 * 3600.0
    """Seconds after log-in after which a session ends whatever happens."""
    free_failures: int = 3
    """Failed log-ins of one user name from one address before back-off starts."""
    base_backoff: float = 2.0
    max_backoff: float = 5 * 60.0
    failure_window: float = 3600.0
    """Failures older than this are forgotten."""


@dataclass(frozen=True, slots=True)
class User:
    name: str
    role: Role
    created: float


@dataclass(frozen=True, slots=True)
class Session:
    user: User
    csrf: str
    created: float
    expires: float


@dataclass(frozen=True, slots=True)
class LoginResult:
    session_token: str | None
    session: Session | None
    retry_after: float = 0.0
    """When refused because of back-off: seconds until the next attempt is heard."""


@dataclass(frozen=True, slots=True)
class AuditEntry:
    id: int
    time: float
    user: str
    action: str
    target: str
    outcome: str
    address: str
    detail: str


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class Auth:
    """The station's accounts and sessions in the station database (thread-safe)."""

    def __init__(self, path: str | Path | Database, policy: AuthPolicy | None = None,
                 clock: Callable[[], float] = time.time,
                 hasher: PasswordHasher | None = None) -> None:
        self.policy = policy or AuthPolicy()
        self.clock = clock
        self.database = open_database(path)
        self.path = self.database.url
        self.hasher = hasher or PasswordHasher()  # argon2id, the library's default type
        self._lock = threading.Lock()
        self._db = ReconnectingConnection(self.database)
        with self._lock:
            if self.database.dialect == "sqlite" and not self.database.memory:
                self._db.execute("PRAGMA journal_mode=WAL")
            schema.ensure_part(self.database, self._db, "accounts")
        self._dummy_hash = self.hasher.hash(secrets.token_hex(16))

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # ---- users -------------------------------------------------------------------------

    def add_user(self, name: str, password: str, role: Role, *, by: str = "cli",
                 address: str = "local") -> User:
        if not USER_NAME.match(name):
            raise StationAuthError("a user name is 1-64 letters, digits or . _ @ -")
        if (problem := password_problem(name, password)) is not None:
            raise StationAuthError(problem)
        now = self.clock()
        hashed = self.hasher.hash(password)
        with self._lock:
            try:
                self._db.execute("INSERT INTO web_users VALUES (?, ?, ?, ?)",
                                 (name, int(role), hashed, now))
            except DuplicateRow:
                raise StationAuthError(f"user {name!r} exists already") from None
        self.audit(by, "user.add", name, "ok", address, f"role={role.label}")
        return User(name, role, now)

    def _refuse_last_admin(self, name: str, what: str) -> None:
        """Raise when ``name`` is the only admin (call with the lock held): a station
        without an admin can no longer be managed from its pages."""
        row = self._db.execute("SELECT role FROM web_users WHERE name = ?", (name,)).fetchone()
        if row is None or row[0] != int(Role.ADMIN):
            return
        admins = self._db.execute("SELECT COUNT(*) FROM web_users WHERE role = ?",
                                  (int(Role.ADMIN),)).fetchone()[0]
        if admins <= 1:
            raise StationAuthError(f"{name!r} is the last admin and cannot be {what}; "
                            "make another admin first")

    def set_role(self, name: str, role: Role, *, by: str, address: str) -> None:
        with self._lock:
            if role != Role.ADMIN:
                self._refuse_last_admin(name, "demoted")
            changed = self._db.execute("UPDATE web_users SET role = ? WHERE name = ?",
                                       (int(role), name)).rowcount
        if not changed:
            raise StationAuthError(f"no user {name!r}")
        self.audit(by, "user.role", name, "ok", address, f"role={role.label}")

    def set_password(self, name: str, password: str, *, by: str, address: str) -> None:
        if (problem := password_problem(name, password)) is not None:
            raise StationAuthError(problem)
        hashed = self.hasher.hash(password)
        with self._lock:
            changed = self._db.execute("UPDATE web_users SET hash = ? WHERE name = ?",
                                       (hashed, name)).rowcount
            self._db.execute('DELETE FROM web_sessions WHERE "user" = ?', (name,))
        if not changed:
            raise StationAuthError(f"no user {name!r}")
        self.audit(by, "user.password", name, "ok", address, "")

    def remove_user(self, name: str, *, by: str, address: str) -> None:
        with self._lock:
            self._refuse_last_admin(name, "removed")
            self._db.execute('DELETE FROM web_sessions WHERE "user" = ?', (name,))
            removed = self._db.execute("DELETE FROM web_users WHERE name = ?",
                                       (name,)).rowcount
        if not removed:
            raise StationAuthError(f"no user {name!r}")
        self.audit(by, "user.remove", name, "ok", address, "")

    def users(self) -> list[User]:
        with self._lock:
            rows = self._db.execute(
                "SELECT name, role, created FROM web_users ORDER BY name").fetchall()
        return [User(n, Role(r), c) for n, r, c in rows]

    def user(self, name: str) -> User | None:
        with self._lock:
            row = self._db.execute("SELECT name, role, created FROM web_users WHERE name = ?",
                                   (name,)).fetchone()
        return User(row[0], Role(row[1]), row[2]) if row else None

    # ---- log-in ------------------------------------------------------------------------

    @staticmethod
    def _failure_key(name: str, address: str) -> str:
        return f"pair:{name.lower()}\n{address}"

    def retry_after(self, name: str, address: str) -> float:
        """Seconds this user name must still wait at this address before a log-in is heard."""
        now = self.clock()
        with self._lock:
            row = self._db.execute("SELECT count, last FROM web_login_failures WHERE key = ?",
                                   (self._failure_key(name, address),)).fetchone()
        if row is None or now - row[1] > self.policy.failure_window:
            return 0.0
        excess: int = row[0] - self.policy.free_failures
        if excess < 0:
            return 0.0
        backoff = min(self.policy.max_backoff,
                      self.policy.base_backoff * 2.0 ** min(excess, 30))
        last: float = row[1]
        return max(0.0, last + backoff - now)

    def _fail(self, name: str, address: str) -> None:
        now = self.clock()
        key = self._failure_key(name, address)
        with self._lock:
            row = self._db.execute("SELECT count, last FROM web_login_failures WHERE key = ?",
                                   (key,)).fetchone()
            count = 1 if row is None or now - row[1] > self.policy.failure_window \
                else row[0] + 1
            self._db.execute("INSERT INTO web_login_failures VALUES (?, ?, ?) ON CONFLICT (key) "
                             "DO UPDATE SET count = excluded.count, last = excluded.last",
                             (key, count, now))
            self._db.execute("DELETE FROM web_login_failures WHERE last < ?",
                             (now - self.policy.failure_window,))

    def log_in(self, name: str, password: str, address: str) -> LoginResult:
        """Check a password; on success open a session and forget past failures."""
        wait = self.retry_after(name, address)
        if wait > 0:
            self.audit(name[:64], "login", name[:64], "throttled", address,
                       f"retry in {wait:.0f} s")
            return LoginResult(None, None, wait)
        with self._lock:
            row = self._db.execute("SELECT hash, role, created FROM web_users WHERE name = ?",
                                   (name,)).fetchone()
        stored = row[0] if row else self._dummy_hash  # same work whether the user exists
        try:
            ok = self.hasher.verify(stored, password) and row is not None
        except (VerifyMismatchError, VerificationError, InvalidHashError):
            ok = False
        if not ok or row is None:
            self._fail(name, address)
            self.audit(name[:64], "login", name[:64], "refused", address, "wrong name or password")
            return LoginResult(None, None, 0.0)
        if self.hasher.check_needs_rehash(stored):
            with self._lock:
                self._db.execute("UPDATE web_users SET hash = ? WHERE name = ?",
                                 (self.hasher.hash(password), name))
        token = secrets.token_urlsafe(32)
        csrf = secrets.token_urlsafe(32)
        now = self.clock()
        with self._lock:
            self._db.execute("INSERT INTO web_sessions VALUES (?, ?, ?, ?, ?)",
                             (_digest(token), name, csrf, now, now))
            self._db.execute("DELETE FROM web_login_failures WHERE key = ?",
                             (self._failure_key(name, address),))
            self._db.execute("DELETE FROM web_sessions WHERE created < ?",
                             (now - self.policy.max_age,))
        self.audit(name, "login", name, "ok", address, "")
        user = User(name, Role(row[1]), row[2])
        return LoginResult(token, Session(user, csrf, now, self._expiry(now, now)))

    def _expiry(self, created: float, last_seen: float) -> float:
        return min(created + self.policy.max_age, last_seen + self.policy.idle_timeout)

    def session(self, token: str | None, *, touch: bool = True) -> Session | None:
        """The live session of this cookie value, or ``None`` (unknown, expired)."""
        if not token or len(token) > 200:
            return None
        now = self.clock()
        digest = _digest(token)
        with self._lock:
            row = self._db.execute(
                "SELECT s.csrf, s.created, s.last_seen, u.name, u.role, u.created "
                "FROM web_sessions s JOIN web_users u ON u.name = s.\"user\" "
                "WHERE s.token_hash = ?", (digest,)).fetchone()
            if row is None:
                return None
            csrf, created, last_seen, name, role, user_created = row
            if now >= self._expiry(created, last_seen):
                self._db.execute("DELETE FROM web_sessions WHERE token_hash = ?", (digest,))
                return None
            if touch:
                self._db.execute("UPDATE web_sessions SET last_seen = ? WHERE token_hash = ?",
                                 (now, digest))
                last_seen = now
        return Session(User(name, Role(role), user_created), csrf, created,
                       self._expiry(created, last_seen))

    def log_out(self, token: str, address: str) -> None:
        session = self.session(token, touch=False)
        with self._lock:
            self._db.execute("DELETE FROM web_sessions WHERE token_hash = ?", (_digest(token),))
        if session is not None:
            self.audit(session.user.name, "logout", session.user.name, "ok", address, "")

    @staticmethod
    def csrf_matches(session: Session, presented: str | None) -> bool:
        return bool(presented) and hmac.compare_digest(session.csrf.encode(),
                                                       str(presented).encode())

    # ---- audit -------------------------------------------------------------------------

    def audit(self, user: str, action: str, target: str, outcome: str, address: str,
              detail: str = "") -> None:
        with self._lock:
            self._db.execute(
                "INSERT INTO web_audit (time, \"user\", action, target, outcome, address, detail) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)",
                (self.clock(), user, action, target[:500], outcome, address, detail[:2000]))

    def audit_log(self, limit: int = 200, **match: Any) -> list[AuditEntry]:
        where = " AND ".join(f'"{k}" = ?' for k in match if k in ("user", "action", "outcome"))
        sql = ("SELECT id, time, \"user\", action, target, outcome, address, detail "
               "FROM web_audit") + (f" WHERE {where}" if where else "") + \
            " ORDER BY id DESC LIMIT ?"
        with self._lock:
            rows = self._db.execute(sql, (*[v for k, v in match.items()
                                            if k in ("user", "action", "outcome")],
                                          limit)).fetchall()
        return [AuditEntry(*r) for r in rows]
