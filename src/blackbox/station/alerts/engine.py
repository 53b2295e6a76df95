"""From what the station heard to alerts and notifications in the outbox.

The engine follows the store's event timeline (:meth:`StationStore.events_after`, from a
cursor kept in the database) and, on each :meth:`AlertEngine.tick`, the fleet's silence
and the station's own problems. Time is passed in (``now``), so escalation and rate limits
are tested without waiting.

* **Matching**: every rule that matches an input gets an alert keyed by (rule, robot,
  entity, kind). While that alert is open, more inputs with the key only count up (dedup).
* **Lasting**: a rule with ``lasting`` holds its alert ``pending`` until the condition has
  lasted that long; rectified before, it is resolved without a message.
* **Rate limit and digest**: a rule sends at most ``rate_limit.count`` messages per
  ``rate_limit.per`` seconds; the rest are counted and, when the window ends, sent as one
  digest (how many, with examples). Nothing is dropped silently.
* **Escalation**: a fired alert not acknowledged ``escalate[i].after`` seconds after it
  fired goes to ``escalate[i].send`` too. Acknowledging (page, API, the event's own
  acknowledgement) stops it; recovery sends ``resolved`` to every channel told so far.
* **Unmatched**: while rules exist, an input that matches none is counted (page, metrics).
* **Audit**: every step (fired, escalated, acknowledged, resolved, suppressed, digest,
  delivery failed, rule added/removed, test) goes to the audit callback.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from blackbox.config.node import ConfigError
from blackbox.errors import BlackBoxError
from blackbox.station.alerts.db import AlertDB
from blackbox.station.alerts.outbox import Outbox
from blackbox.station.alerts.rules import (
    ALERT_KINDS,
    AlertConfig,
    AlertInput,
    Rule,
    parse_rule_text,
)
from blackbox.station.database import Connection
from blackbox.station.store import Event, StationStore

Audit = Callable[[str, str, str, str, str], None]
"""``audit(user, action, target, outcome, detail)``."""

OPEN_STATES = ("pending", "firing", "acknowledged")
UNMATCHED_KEEP = 7 * 86400.0
HISTORY_KEEP = 30 * 86400.0
"""Resolved alerts and delivered messages are kept this long (seconds)."""
MAX_EXAMPLES = 10
SCHEMA = "blackbox.alert/1"


_RATE_RESTART = ("INSERT INTO alert_rate VALUES (?, ?, 1, 0, '[]') ON CONFLICT (rule) DO UPDATE "
                 "SET window_start = excluded.window_start, sent = 1, suppressed = 0, "
                 "examples = '[]'")
"""A rule's rate window starts again at ``now`` with one alert sent."""

class AlertRuleError(BlackBoxError, ValueError):
    """A rule change the engine refuses; the message is safe to show."""


@dataclass(frozen=True, slots=True)
class Alert:
    id: int
    rule: str
    robot: str
    entity: str
    kind: str
    status: str
    text: str
    event_id: int | None
    first: float
    last: float
    count: int
    state: str
    """``pending`` (waiting for ``lasting``), ``firing``, ``acknowledged``, ``resolved``."""
    fired_at: float | None
    level: int
    """Escalation steps taken (0: only the rule's ``send`` channels were told)."""
    acked_by: str | None
    acked_at: float | None
    resolved_at: float | None
    notified: bool
    """Its alert message went out (``False``: held back by the rate limit, counted in a
    digest; its resolution is then not sent either)."""

    def as_json(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in Alert.__slots__}


_ALERT_SELECT = ("SELECT id, rule, robot, entity, kind, status, text, event_id, first, last, "
                 "count, state, fired_at, level, acked_by, acked_at, resolved_at, notified "
                 "FROM alert_alerts")


def _alert(r: Sequence[Any]) -> Alert:
    return Alert(r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11],
                 r[12], r[13], r[14], r[15], r[16], bool(r[17]))


def _nobody(user: str, action: str, target: str, outcome: str, detail: str) -> None:
    return None


class AlertEngine:
    def __init__(self, store: StationStore, db: AlertDB, config: AlertConfig,
                 outbox: Outbox, audit: Audit = _nobody) -> None:
        self.store = store
        self.db = db
        self.config = config
        self.outbox = outbox
        self.audit = audit
        self._page_cache: list[Rule] | None = None
        self._silent: set[str] = set()
        self._problems: set[str] = set()
        if self.db.meta("event_cursor") is None:  # a new station alerts on what is new
            with self.db.transaction() as tx:
                self.db.set_meta(tx, "event_cursor", str(store.last_event_id()))

    # ---- rules -------------------------------------------------------------------------

    @property
    def rules(self) -> tuple[Rule, ...]:
        """The file's rules, then the page's (a page rule never shadows a file rule)."""
        return (*self.config.rules, *self._page_rules())

    def _page_rules(self) -> list[Rule]:
        """Parsed once after each change (rules are matched against every event)."""
        cached = self._page_cache
        if cached is not None:
            return cached
        with self.db.reading() as db:
            rows = db.execute("SELECT name, text FROM alert_rules ORDER BY created").fetchall()
        rules = []
        for name, text in rows:
            try:
                rules.append(parse_rule_text(text, self.config, "page", f"rule {name!r}"))
            except ConfigError as exc:  # a channel left the file since: visible, not lost
                self.store.report_problem("alerts", f"page rule {name!r} no longer valid: "
                                                    f"{exc}")
        self._page_cache = rules
        return rules

    def rule(self, name: str) -> Rule | None:
        return next((r for r in self.rules if r.name == name), None)

    def add_rule(self, text: str, user: str, now: float) -> Rule:
        """Check and store a rule written in the page; refuses a name taken by any rule."""
        try:
            rule = parse_rule_text(text, self.config, "page")
        except ConfigError as exc:
            self.audit(user, "alert.rule.add", "", "refused", str(exc))
            raise AlertRuleError(str(exc)) from None
        if self.rule(rule.name) is not None:
            self.audit(user, "alert.rule.add", rule.name, "refused", "name taken")
            raise AlertRuleError(f"a rule named {rule.name!r} exists already")
        with self.db.transaction() as db:
            db.execute("INSERT INTO alert_rules VALUES (?, ?, ?, ?)",
                       (rule.name, text, now, user))
        self._page_cache = None
        self.audit(user, "alert.rule.add", rule.name, "ok", "")
        return rule

    def remove_rule(self, name: str, user: str) -> None:
        with self.db.transaction() as db:
            removed = db.execute("DELETE FROM alert_rules WHERE name = ?", (name,)).rowcount
        self._page_cache = None
        if not removed:
            why = ("rules of the alerts file are changed in the file"
                   if any(r.name == name for r in self.config.rules) else "no such page rule")
            self.audit(user, "alert.rule.remove", name, "refused", why)
            raise AlertRuleError(why)
        self.audit(user, "alert.rule.remove", name, "ok", "")

    def send_test(self, name: str, user: str, now: float) -> list[int]:
        """A test notification to every channel of rule ``name``; the outbox rows."""
        rule = self.rule(name)
        if rule is None:
            self.audit(user, "alert.test", name, "refused", "no such rule")
            raise AlertRuleError(f"no rule {name!r}")
        payload = self._payload("test", rule, None, now, summary=(
            f"Test notification of rule {rule.name!r}, sent by {user}"))
        ids = [self.outbox.enqueue(None, rule.name, c, "test", payload, now)
               for c in rule.channels]
        self.audit(user, "alert.test", name, "ok", f"outbox={ids}")
        return ids

    # ---- inputs ------------------------------------------------------------------------

    def poll(self, now: float, batch: int = 500) -> int:
        """Handle the events stored since the last poll; returns how many were read."""
        cursor = int(self.db.meta("event_cursor") or 0)
        events = self.store.events_after(cursor, batch)
        statuses: dict[int, str] = {}  # one read per robot and poll, not per event
        # (not one transaction for the poll: the audit log is written through another
        # connection, which would wait for this one's lock on SQLite)
        for event in events:
            self._event(event, now, statuses)
        if events:
            with self.db.transaction() as tx:
                self.db.set_meta(tx, "event_cursor", str(events[-1].id))
        return len(events)

    def _event(self, event: Event, now: float, statuses: dict[int, str]) -> None:
        if event.origin == "log":  # history fetched from a robot's log: not news
            return
        robot = event.robot_id
        if event.kind == "rectification":
            self.resolve(robot, event.entity, ("failure", "exceedance"), now)
        elif event.kind == "state_change":  # back between healthy states
            self.resolve(robot, event.entity, ("exceedance",), now)
        elif event.kind == "acknowledgement" and event.refers_to is not None:
            who = str(event.details.get("user") or "station")
            for alert in self.alerts(event_id=event.refers_to, open_only=True):
                self.acknowledge(alert.id, who, now, via="event")
        elif event.kind == "diagnosis" and not event.details.get("components"):
            self.resolve(robot, "", ("diagnosis",), now)
        elif event.kind in ALERT_KINDS:
            status = self._status(event, statuses)
            self.handle(AlertInput(event.kind, robot, event.entity, status, event.text,
                                   event.time, event.id), now)

    def _status(self, event: Event, statuses: dict[int, str]) -> str:
        """The robot's status as the poll found it (its events of one poll were all stored
        before the poll read them, so one read serves them all)."""
        rid = event.resource_id
        if rid not in statuses:
            try:
                statuses[rid] = self.store.robot(rid).status
            except LookupError:
                statuses[rid] = "UNKNOWN"
        return statuses[rid]

    def handle(self, item: AlertInput, now: float) -> list[int]:
        """Match one input; returns the ids of the alerts it opened or counted on."""
        rules = self.rules
        matched = [r for r in rules if r.matches(item)]
        if not matched:
            if rules:
                with self.db.transaction() as db:
                    db.execute("INSERT INTO alert_unmatched (time, kind, robot) VALUES "
                               "(?, ?, ?)", (item.time if item.time > 0 else now, item.kind,
                                             item.robot))
                    db.execute("DELETE FROM alert_unmatched WHERE time < ?",
                               (now - UNMATCHED_KEEP,))
            return []
        return [self._open(rule, item, now) for rule in matched]

    def _open(self, rule: Rule, item: AlertInput, now: float) -> int:
        key = f"{rule.name}|{item.robot}|{item.entity}|{item.kind}"
        with self.db.transaction() as db:
            row = db.execute("SELECT id FROM alert_alerts WHERE key = ? AND state IN "
                             "('pending', 'firing', 'acknowledged')", (key,)).fetchone()
            if row is not None:
                db.execute("UPDATE alert_alerts SET last = ?, count = count + 1, text = ?, "
                           "status = ? WHERE id = ?", (now, item.text[:2000], item.status,
                                                       row[0]))
                return int(row[0])
            alert_id = db.insert(
                "INSERT INTO alert_alerts (rule, key, robot, entity, kind, status, text, "
                "event_id, first, last, count, state) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                "1, 'pending')", (rule.name, key, item.robot, item.entity, item.kind,
                                  item.status, item.text[:2000], item.event_id, now, now))
        if rule.lasting <= 0:
            self._fire(rule, alert_id, now)
        return alert_id

    def _fire(self, rule: Rule, alert_id: int, now: float) -> None:
        with self.db.transaction() as db:
            db.execute("UPDATE alert_alerts SET state = 'firing', fired_at = ? WHERE id = ? "
                       "AND state = 'pending'", (now, alert_id))
        alert = self.alert(alert_id)
        assert alert is not None
        sent = self._notify(rule, alert, "alert", rule.send, now)
        if not sent:
            with self.db.transaction() as db:
                db.execute("UPDATE alert_alerts SET notified = 0 WHERE id = ?", (alert_id,))
        self.audit("station", "alert.fire", self._target(alert), "ok" if sent else "suppressed",
                   f"rule={rule.name}")

    def _notify(self, rule: Rule, alert: Alert, purpose: str, channels: Sequence[str],
                now: float) -> bool:
        """Put a message into the outbox unless the rule's rate limit is reached (then
        count it for the digest). Resolutions and escalations always go out."""
        with self.db.transaction() as db:
            if purpose == "alert" and not self._within_limit(db, rule, alert, now):
                return False
        payload = self._payload(purpose, rule, alert, now)
        for channel in channels:
            self.outbox.enqueue(alert.id, rule.name, channel, purpose, payload, now)
        return True

    def _within_limit(self, db: Connection, rule: Rule, alert: Alert,
                      now: float) -> bool:
        row = db.execute("SELECT window_start, sent, suppressed, examples FROM alert_rate "
                         "WHERE rule = ?", (rule.name,)).fetchone()
        if row is None or now - row[0] >= rule.rate_limit.per:
            if row is not None and row[2] > 0:  # the window ended with a digest to send
                return self._digest_then_count(db, rule, row, now)
            db.execute(_RATE_RESTART,
                       (rule.name, now))
            return True
        if row[1] < rule.rate_limit.count:
            db.execute("UPDATE alert_rate SET sent = sent + 1 WHERE rule = ?", (rule.name,))
            return True
        examples = json.loads(row[3])
        if len(examples) < MAX_EXAMPLES:
            examples.append(f"{alert.robot} {alert.entity} {alert.kind}: {alert.text[:200]}")
        db.execute("UPDATE alert_rate SET suppressed = suppressed + 1, examples = ? "
                   "WHERE rule = ?", (json.dumps(examples), rule.name))
        return False

    def _digest_then_count(self, db: Connection, rule: Rule, row: Sequence[Any],
                           now: float) -> bool:
        self._enqueue_digest(rule, int(row[2]), json.loads(row[3]), now)
        db.execute(_RATE_RESTART,
                   (rule.name, now))
        return True

    def _enqueue_digest(self, rule: Rule, suppressed: int, examples: list[str],
                        now: float) -> None:
        payload = self._payload("digest", rule, None, now, summary=(
            f"{suppressed} more alert(s) of rule {rule.name!r} were held back by its rate "
            f"limit ({rule.rate_limit.count} per {rule.rate_limit.per:g} s)"))
        payload["suppressed"] = suppressed
        payload["suppressed_examples"] = examples
        for channel in rule.send:
            self.outbox.enqueue(None, rule.name, channel, "digest", payload, now)
        self.audit("station", "alert.digest", rule.name, "ok", f"suppressed={suppressed}")

    def _payload(self, purpose: str, rule: Rule, alert: Alert | None, now: float,
                 summary: str = "") -> dict[str, Any]:
        body: dict[str, Any] = {"schema": SCHEMA, "type": purpose, "rule": rule.name,
                                "sent": now}
        if alert is not None:
            body["alert"] = {k: v for k, v in alert.as_json().items()}
            body["summary"] = summary or _summary(purpose, alert)
            if self.config.station_url:
                body["ack_url"] = f"{self.config.station_url}/alerts/{alert.id}"
        else:
            body["summary"] = summary
        return body

    # ---- state changes -------------------------------------------------------------------

    def resolve(self, robot: str, entity: str, kinds: Sequence[str], now: float) -> list[int]:
        """Resolve the open alerts of ``robot``/``entity`` of ``kinds``; fired ones send
        ``resolved`` to every channel told so far."""
        marks = ",".join("?" for _ in kinds)
        with self.db.transaction() as db:
            rows = db.execute(_ALERT_SELECT + f" WHERE robot = ? AND entity = ? AND kind IN "
                              f"({marks}) AND state IN ('pending', 'firing', 'acknowledged')",
                              (robot, entity, *kinds)).fetchall()
            db.execute(f"UPDATE alert_alerts SET state = 'resolved', resolved_at = ? WHERE "
                       f"robot = ? AND entity = ? AND kind IN ({marks}) AND state IN "
                       "('pending', 'firing', 'acknowledged')", (now, robot, entity, *kinds))
        for alert in map(_alert, rows):
            rule = self.rule(alert.rule)
            if alert.state != "pending" and alert.notified and rule is not None:
                told = list(rule.send)
                for step in rule.escalate[: alert.level]:
                    told.extend(c for c in step.send if c not in told)
                self._notify(rule, self.alert(alert.id) or alert, "resolved", told, now)
            self.audit("station", "alert.resolve", self._target(alert), "ok",
                       "before it lasted long enough" if alert.state == "pending" else "")
        return [a[0] for a in rows]

    def acknowledge(self, alert_id: int, user: str, now: float, via: str = "page") -> Alert:
        """Stop an alert's escalation; acknowledging twice keeps the first. Raises
        ``LookupError`` for an unknown alert."""
        with self.db.transaction() as db:
            found = db.execute("SELECT state FROM alert_alerts WHERE id = ?",
                               (alert_id,)).fetchone()
            if found is None:
                raise LookupError(f"no alert {alert_id}")
            changed = db.execute("UPDATE alert_alerts SET state = 'acknowledged', "
                                 "acked_by = ?, acked_at = ? WHERE id = ? AND state IN "
                                 "('pending', 'firing')", (user[:100], now, alert_id)).rowcount
        alert = self.alert(alert_id)
        assert alert is not None
        self.audit(user, "alert.ack", self._target(alert), "ok" if changed else "unchanged",
                   f"via={via}" + ("" if changed else f"; already {found[0]}"))
        return alert

    def tick(self, now: float) -> None:
        """Time-driven work: silent robots, station problems, ``lasting``, escalation,
        digests of ended rate windows."""
        self._watch_fleet(now)
        self._watch_problems(now)
        rules = {r.name: r for r in self.rules}
        for alert in self.alerts(state="pending", limit=1000):
            rule = rules.get(alert.rule)
            if rule is not None and now >= alert.first + rule.lasting:
                self._fire(rule, alert.id, now)
        for alert in self.alerts(state="firing", limit=1000):
            rule = rules.get(alert.rule)
            if rule is None or alert.level >= len(rule.escalate) or alert.fired_at is None:
                continue
            step = rule.escalate[alert.level]
            if now >= alert.fired_at + step.after:
                with self.db.transaction() as db:
                    db.execute("UPDATE alert_alerts SET level = level + 1 WHERE id = ? AND "
                               "level = ?", (alert.id, alert.level))
                escalated = self.alert(alert.id) or alert
                self._notify(rule, escalated, "escalation", step.send, now)
                self.audit("station", "alert.escalate", self._target(alert), "ok",
                           f"step={alert.level + 1} to {','.join(step.send)}")
        with self.db.transaction() as db:
            for name, start, suppressed, examples in db.execute(
                    "SELECT rule, window_start, suppressed, examples FROM alert_rate "
                    "WHERE suppressed > 0").fetchall():
                rule = rules.get(name)
                if rule is None or now - start < rule.rate_limit.per:
                    continue
                self._enqueue_digest(rule, int(suppressed), json.loads(examples), now)
                db.execute("UPDATE alert_rate SET window_start = ?, sent = 0, "
                           "suppressed = 0, examples = '[]' WHERE rule = ?", (now, name))

    def prune(self, now: float) -> int:
        """Forget resolved alerts and delivered messages older than :data:`HISTORY_KEEP`
        (the database stays bounded however long the station runs)."""
        with self.db.transaction() as db:
            gone = db.execute("DELETE FROM alert_alerts WHERE state = 'resolved' AND "
                              "resolved_at < ?", (now - HISTORY_KEEP,)).rowcount
        return int(gone) + self.outbox.prune(now - HISTORY_KEEP)

    def _watch_fleet(self, now: float) -> None:
        for rid, robot_id, last_heard in self.store.heard_times():
            name = robot_id or f"#{rid}"
            stale = last_heard is None or now - last_heard > self.store.stale_after
            if stale and name not in self._silent:
                self._silent.add(name)
                self.handle(AlertInput("robot_silent", name, name, "UNKNOWN",
                                       f"{name} has not been heard for more than "
                                       f"{self.store.stale_after:g} s", now), now)
            elif not stale and name in self._silent:
                self._silent.discard(name)
                self.resolve(name, name, ("robot_silent",), now)

    def _watch_problems(self, now: float) -> None:
        current = {p.source: p for p in self.store.problems(200)}
        for source, problem in current.items():
            if source not in self._problems:
                self._problems.add(source)
                self.handle(AlertInput("station_problem", "station", source, "UNKNOWN",
                                       problem.message, now), now)
        for source in list(self._problems - set(current)):
            self._problems.discard(source)
            self.resolve("station", source, ("station_problem",), now)

    # ---- reading -------------------------------------------------------------------------

    def alert(self, alert_id: int) -> Alert | None:
        with self.db.reading() as db:
            row = db.execute(_ALERT_SELECT + " WHERE id = ?", (alert_id,)).fetchone()
        return None if row is None else _alert(row)

    def alerts(self, *, state: str | None = None, open_only: bool = False,
               event_id: int | None = None, limit: int = 100) -> list[Alert]:
        where, args = [], list[Any]()
        if state is not None:
            where.append("state = ?")
            args.append(state)
        if open_only:
            where.append("state IN ('pending', 'firing', 'acknowledged')")
        if event_id is not None:
            where.append("event_id = ?")
            args.append(event_id)
        sql = _ALERT_SELECT + (" WHERE " + " AND ".join(where) if where else "") + \
            " ORDER BY id DESC LIMIT ?"
        with self.db.reading() as db:
            return [_alert(r) for r in db.execute(sql, [*args, max(1, min(limit, 1000))])]

    def unmatched(self, since: float) -> dict[str, int]:
        """Inputs of each kind since ``since`` that matched no rule."""
        with self.db.reading() as db:
            rows = db.execute("SELECT kind, count(*) FROM alert_unmatched WHERE time >= ? "
                              "GROUP BY kind ORDER BY kind", (since,)).fetchall()
        return {k: int(n) for k, n in rows}

    def unmatched_total(self) -> dict[str, int]:
        with self.db.reading() as db:
            rows = db.execute("SELECT kind, count(*) FROM alert_unmatched "
                              "GROUP BY kind").fetchall()
        return {k: int(n) for k, n in rows}

    def counts(self) -> dict[tuple[str, str], int]:
        """Alerts by (rule, state), for the metrics."""
        with self.db.reading() as db:
            rows = db.execute("SELECT rule, state, count(*) FROM alert_alerts "
                              "GROUP BY rule, state").fetchall()
        return {(r, s): int(n) for r, s, n in rows}

    @staticmethod
    def _target(alert: Alert) -> str:
        return f"alert {alert.id} {alert.robot}:{alert.entity}:{alert.kind}"


def _summary(purpose: str, alert: Alert) -> str:
    what = f"{alert.robot} {alert.entity}".strip()
    if purpose == "resolved":
        return f"RESOLVED: {what} {alert.kind} is over"
    if purpose == "escalation":
        return f"ESCALATED (not acknowledged): {what} {alert.kind}: {alert.text}"
    return f"{what} {alert.kind}: {alert.text}"
