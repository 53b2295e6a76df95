"""Per-user API tokens for ``/api/v1``: created and revoked in the page, stored hashed.

A token is ``bbt_<id>_<secret>``; the database keeps only the SHA-256 of the secret (a
stolen database opens nothing). A token acts with its user's *current* role (changing or
removing the user changes or ends what the token may do), until it expires or is revoked.
Table ``web_api_tokens`` in the station database, beside the accounts.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from blackbox.station import schema
from blackbox.station.auth import Auth, StationAuthError, User
from blackbox.station.database import Database, ReconnectingConnection, open_database

PREFIX = "bbt_"
MAX_DAYS = 366


@dataclass(frozen=True, slots=True)
class ApiToken:
    id: int
    user: str
    name: str
    created: float
    expires: float
    revoked: float | None
    last_used: float | None


class ApiTokens:
    def __init__(self, path: str | Path | Database, auth: Auth,
                 clock: Callable[[], float] = time.time) -> None:
        self.auth = auth
        self.clock = clock
        self._lock = threading.Lock()
        self.database = open_database(path)
        self._db = ReconnectingConnection(self.database)
        with self._lock:
            schema.ensure_part(self.database, self._db, "tokens")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def create(self, user: str, name: str, days: float, address: str = "local"
               ) -> tuple[str, ApiToken]:
        """A new token of ``user``; the clear text is returned once and never again."""
        if not 0 < days <= MAX_DAYS:
            raise StationAuthError(f"a token expires after 1 to {MAX_DAYS} days")
        name = name.strip()[:100] or "token"
        secret = secrets.token_urlsafe(32)
        now = self.clock()
        with self._lock:
            token_id = self._db.insert(
                "INSERT INTO web_api_tokens (\"user\", name, hash, created, expires) "
                "VALUES (?, ?, ?, ?, ?)",
                (user, name, hashlib.sha256(secret.encode()).hexdigest(), now,
                 now + days * 86400.0))
        self.auth.audit(user, "token.create", f"token {token_id}", "ok", address,
                        f"name={name} days={days:g}")
        return f"{PREFIX}{token_id}_{secret}", ApiToken(token_id, user, name, now,
                                                       now + days * 86400.0, None, None)

    def revoke(self, token_id: int, by: User, address: str = "local") -> None:
        """Revoke a token: its owner may, an admin may revoke anyone's."""
        from blackbox.station.auth import Role

        with self._lock:
            row = self._db.execute('SELECT "user" FROM web_api_tokens WHERE id = ?',
                                   (token_id,)).fetchone()
            if row is None or (row[0] != by.name and by.role < Role.ADMIN):
                allowed = False
            else:
                allowed = True
                self._db.execute("UPDATE web_api_tokens SET revoked = ? WHERE id = ? AND "
                                 "revoked IS NULL", (self.clock(), token_id))
        self.auth.audit(by.name, "token.revoke", f"token {token_id}",
                        "ok" if allowed else "refused", address, "")
        if not allowed:
            raise StationAuthError("no such token of yours")

    def tokens(self, user: str | None = None) -> list[ApiToken]:
        sql = ('SELECT id, "user", name, created, expires, revoked, last_used '
               "FROM web_api_tokens")
        args: tuple[str, ...] = ()
        if user is not None:
            sql += ' WHERE "user" = ?'
            args = (user,)
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY id DESC", args).fetchall()
        return [ApiToken(*r) for r in rows]

    def user_of(self, presented: str | None) -> User | None:
        """The user a presented token acts for, or ``None`` (unknown, malformed, expired,
        revoked, or its user removed)."""
        if not presented or not presented.startswith(PREFIX) or len(presented) > 200:
            return None
        id_text, sep, secret = presented[len(PREFIX):].partition("_")
        if not sep or not id_text.isdigit():
            return None
        now = self.clock()
        with self._lock:
            row = self._db.execute('SELECT "user", hash, expires, revoked FROM web_api_tokens '
                                   "WHERE id = ?", (int(id_text),)).fetchone()
            if row is None:
                return None
            user, digest, expires, revoked = row
            if not hmac.compare_digest(digest, hashlib.sha256(secret.encode()).hexdigest()) \
                    or revoked is not None or now >= expires:
                return None
            self._db.execute("UPDATE web_api_tokens SET last_used = ? WHERE id = ?",
                             (now, int(id_text)))
        return self.auth.user(user)
