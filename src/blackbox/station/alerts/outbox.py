"""The persistent outbox: every notification is a row before anyone tries to send it.

A row is ``pending`` until a channel accepts it (``sent``) or the last attempt of the
:class:`~blackbox.station.alerts.rules.Delivery` policy fails (``failed``, a visible
problem). Between attempts the row waits ``backoff * 2**(attempt-1)`` seconds, capped.
A station that stops in the middle of an attempt sends the row again after its restart:
delivery is at least once, and receivers can drop repeats by ``X-Blackbox-Delivery``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from blackbox.station.alerts.channels import Outcome
from blackbox.station.alerts.db import AlertDB
from blackbox.station.alerts.rules import Delivery

PURPOSES = ("alert", "escalation", "resolved", "digest", "test")


@dataclass(frozen=True, slots=True)
class OutboxEntry:
    id: int
    alert_id: int | None
    rule: str
    channel: str
    purpose: str
    payload: dict[str, Any]
    created: float
    attempts: int
    next_attempt: float
    state: str
    last_error: str
    finished: float | None


_SELECT = ("SELECT id, alert_id, rule, channel, purpose, payload, created, attempts, "
           "next_attempt, state, last_error, finished FROM alert_outbox")


def _entry(r: Any) -> OutboxEntry:
    return OutboxEntry(r[0], r[1], r[2], r[3], r[4], json.loads(r[5]), r[6], r[7], r[8], r[9],
                       r[10], r[11])


class Outbox:
    def __init__(self, db: AlertDB, delivery: Delivery) -> None:
        self.db = db
        self.delivery = delivery

    def enqueue(self, alert_id: int | None, rule: str, channel: str, purpose: str,
                payload: dict[str, Any], now: float) -> int:
        if purpose not in PURPOSES:
            raise ValueError(f"unknown purpose {purpose!r}")
        with self.db.transaction() as db:
            return db.insert("INSERT INTO alert_outbox (alert_id, rule, channel, purpose, "
                             "payload, created, next_attempt) VALUES (?, ?, ?, ?, ?, ?, ?)",
                             (alert_id, rule, channel, purpose,
                              json.dumps(payload, default=str), now, now))

    def due(self, now: float, limit: int = 50, busy: frozenset[int] = frozenset()
            ) -> list[OutboxEntry]:
        """Pending rows whose time has come, oldest first, except those in ``busy``."""
        with self.db.reading() as db:
            rows = db.execute(_SELECT + " WHERE state = 'pending' AND next_attempt <= ? "
                              "ORDER BY next_attempt, id LIMIT ?",
                              (now, limit + len(busy))).fetchall()
        return [e for e in map(_entry, rows) if e.id not in busy][:limit]

    def next_due(self, busy: frozenset[int] = frozenset()) -> float | None:
        """When the next pending row not in ``busy`` is due."""
        with self.db.reading() as db:
            rows = db.execute("SELECT id, next_attempt FROM alert_outbox WHERE state = "
                              "'pending' ORDER BY next_attempt LIMIT ?",
                              (len(busy) + 1,)).fetchall()
        times = [float(t) for i, t in rows if i not in busy]
        return times[0] if times else None

    def record(self, entry_id: int, outcome: Outcome, now: float) -> str:
        """Note one attempt's outcome; returns the row's new state."""
        with self.db.transaction() as db:
            row = db.execute("SELECT attempts FROM alert_outbox WHERE id = ?",
                             (entry_id,)).fetchone()
            if row is None:
                return "gone"
            attempts = int(row[0]) + 1
            if outcome.ok:
                state, later = "sent", now
            elif attempts >= self.delivery.attempts:
                state, later = "failed", now
            else:
                state, later = "pending", now + self.delivery.delay(attempts)
            db.execute("UPDATE alert_outbox SET attempts = ?, state = ?, next_attempt = ?, "
                       "last_error = ?, finished = ? WHERE id = ?",
                       (attempts, state, later, "" if outcome.ok else outcome.detail[:500],
                        None if state == "pending" else now, entry_id))
        return state

    def entry(self, entry_id: int) -> OutboxEntry | None:
        with self.db.reading() as db:
            row = db.execute(_SELECT + " WHERE id = ?", (entry_id,)).fetchone()
        return None if row is None else _entry(row)

    def entries(self, *, state: str | None = None, alert_id: int | None = None,
                limit: int = 100) -> list[OutboxEntry]:
        where, args = [], list[Any]()
        if state is not None:
            where.append("state = ?")
            args.append(state)
        if alert_id is not None:
            where.append("alert_id = ?")
            args.append(alert_id)
        sql = _SELECT + (" WHERE " + " AND ".join(where) if where else "") + \
            " ORDER BY id DESC LIMIT ?"
        with self.db.reading() as db:
            return [_entry(r) for r in db.execute(sql, [*args, max(1, min(limit, 1000))])]

    def prune(self, before: float) -> int:
        """Forget delivered rows finished before ``before`` (failed rows stay: they are
        problems someone should read); returns how many went."""
        with self.db.transaction() as db:
            return int(db.execute("DELETE FROM alert_outbox WHERE state = 'sent' AND "
                                  "finished < ?", (before,)).rowcount)

    def counts(self) -> dict[tuple[str, str], int]:
        """Rows by (channel, state), for the metrics."""
        with self.db.reading() as db:
            rows = db.execute("SELECT channel, state, count(*) FROM alert_outbox "
                              "GROUP BY channel, state").fetchall()
        return {(c, s): int(n) for c, s, n in rows}
