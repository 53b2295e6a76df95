"""The station database's tables, written once, with versioned migrations for both engines.

Version 1 is the fleet data (robots, entities, characteristics, events, log requests, IBIT).
Version 2 adds, as part of the one versioned schema, the tables that the accounts
(:mod:`blackbox.station.auth`), API tokens (:mod:`blackbox.station.tokens`), trusted robot
keys (:mod:`blackbox.station.enrolment`) and alerts (:mod:`blackbox.station.alerts.db`) used to
create on their own; they use ``IF NOT EXISTS`` because files made before version 2 may hold
them already. Each module still makes sure of its own part (:func:`ensure_part`) so it keeps
working on a file it opens first.

The DDL is SQLite's; :func:`ddl` turns it into PostgreSQL's (``REAL`` -> ``DOUBLE PRECISION``,
``INTEGER`` -> ``BIGINT``, ``AUTOINCREMENT`` keys -> identity columns). Event identities are
unique at the database level (``UNIQUE (resource_id, dedup)``), which is what lets several
station processes ingest the same robots into one PostgreSQL without duplicates.
"""

from __future__ import annotations

import re

from blackbox.station.database import Connection, Database

APPLICATION = "blackbox-station"
SCHEMA_VERSION = 3

FLEET = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE robots (
    resource_id INTEGER PRIMARY KEY,
    robot_id TEXT NOT NULL DEFAULT '',
    first_heard REAL NOT NULL,
    last_heard REAL NOT NULL,
    last_event REAL,
    online INTEGER NOT NULL DEFAULT 1,
    diagnosis TEXT NOT NULL DEFAULT '[]',
    diagnosis_since REAL
);
CREATE TABLE entities (
    resource_id INTEGER NOT NULL,
    instance_id INTEGER NOT NULL,
    name TEXT NOT NULL DEFAULT '',
    kind TEXT NOT NULL DEFAULT '',
    parent INTEGER,
    status TEXT NOT NULL DEFAULT 'UNKNOWN',
    online INTEGER NOT NULL DEFAULT 1,
    bit INTEGER NOT NULL DEFAULT 0,
    failures INTEGER NOT NULL DEFAULT 0,
    cause TEXT NOT NULL DEFAULT '',
    actions TEXT NOT NULL DEFAULT '',
    characteristics TEXT NOT NULL DEFAULT '[]',
    updated REAL,
    PRIMARY KEY (resource_id, instance_id)
);
CREATE TABLE characteristics (
    resource_id INTEGER NOT NULL,
    instance_id INTEGER NOT NULL,
    entity INTEGER,
    name TEXT NOT NULL DEFAULT '',
    observer TEXT NOT NULL DEFAULT '',
    resource TEXT NOT NULL DEFAULT '',
    quantity TEXT NOT NULL DEFAULT '',
    unit TEXT NOT NULL DEFAULT '',
    value REAL,
    time REAL,
    expected_noise REAL,
    exceeded INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (resource_id, instance_id)
);
CREATE TABLE thresholds (
    resource_id INTEGER NOT NULL,
    instance_id INTEGER NOT NULL,
    characteristic INTEGER NOT NULL,
    name TEXT NOT NULL,
    type TEXT NOT NULL,
    value REAL NOT NULL,
    PRIMARY KEY (resource_id, instance_id)
);
CREATE INDEX thresholds_characteristic ON thresholds (resource_id, characteristic);
CREATE TABLE samples (
    resource_id INTEGER NOT NULL,
    characteristic INTEGER NOT NULL,
    time REAL NOT NULL,
    value REAL NOT NULL
);
CREATE INDEX samples_series ON samples (resource_id, characteristic, time);
CREATE INDEX samples_time ON samples (time);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    resource_id INTEGER NOT NULL,
    time REAL NOT NULL,
    kind TEXT NOT NULL,
    entity TEXT NOT NULL DEFAULT '',
    characteristic TEXT NOT NULL DEFAULT '',
    text TEXT NOT NULL DEFAULT '',
    origin TEXT NOT NULL,
    dedup TEXT NOT NULL,
    details TEXT NOT NULL DEFAULT '{}',
    acknowledged_by TEXT,
    acknowledged_at REAL,
    refers_to INTEGER,
    UNIQUE (resource_id, dedup)
);
CREATE INDEX events_time ON events (time, id);
CREATE INDEX events_robot_time ON events (resource_id, time, id);
CREATE TABLE log_requests (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    resource_id INTEGER NOT NULL,
    robot_id TEXT NOT NULL,
    entity TEXT,
    characteristic TEXT,
    since REAL,
    until REAL,
    kinds TEXT NOT NULL DEFAULT '[]',
    requested_by TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL,
    finished REAL,
    status TEXT NOT NULL DEFAULT 'pending',
    message TEXT NOT NULL DEFAULT '',
    rows INTEGER NOT NULL DEFAULT 0,
    pages INTEGER NOT NULL DEFAULT 0,
    progress REAL NOT NULL DEFAULT 0
);
CREATE TABLE log_rows (
    request INTEGER NOT NULL REFERENCES log_requests(id) ON DELETE CASCADE,
    seq INTEGER NOT NULL,
    entry_id INTEGER NOT NULL,
    time REAL NOT NULL,
    kind TEXT NOT NULL,
    entity TEXT,
    characteristic TEXT,
    code INTEGER,
    payload TEXT NOT NULL,
    PRIMARY KEY (request, seq)
);
CREATE TABLE ibit_runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    resource_id INTEGER NOT NULL,
    robot_id TEXT NOT NULL,
    entity TEXT NOT NULL DEFAULT '',
    requested_by TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL,
    finished REAL,
    status TEXT NOT NULL DEFAULT 'pending',
    health TEXT,
    observations INTEGER NOT NULL DEFAULT 0,
    failed INTEGER NOT NULL DEFAULT 0,
    report TEXT NOT NULL DEFAULT '[]'
)
"""

ACCOUNTS = """
CREATE TABLE IF NOT EXISTS web_users (
    name TEXT PRIMARY KEY,
    role INTEGER NOT NULL,
    hash TEXT NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS web_sessions (
    token_hash TEXT PRIMARY KEY,
    "user" TEXT NOT NULL REFERENCES web_users(name) ON DELETE CASCADE,
    csrf TEXT NOT NULL,
    created REAL NOT NULL,
    last_seen REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS web_login_failures (
    key TEXT PRIMARY KEY,
    count INTEGER NOT NULL,
    last REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS web_audit (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time REAL NOT NULL,
    "user" TEXT NOT NULL,
    action TEXT NOT NULL,
    target TEXT NOT NULL,
    outcome TEXT NOT NULL,
    address TEXT NOT NULL,
    detail TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS web_audit_time ON web_audit (time)
"""

TOKENS = """
CREATE TABLE IF NOT EXISTS web_api_tokens (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    "user" TEXT NOT NULL,
    name TEXT NOT NULL,
    hash TEXT NOT NULL,
    created REAL NOT NULL,
    expires REAL NOT NULL,
    revoked REAL,
    last_used REAL
)
"""

ROBOT_KEYS = """
CREATE TABLE IF NOT EXISTS trusted_robots (
    robot_id TEXT PRIMARY KEY,
    public_key TEXT NOT NULL,
    source TEXT NOT NULL,
    enrolled REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS seen_robot_keys (
    robot_id TEXT NOT NULL,
    public_key TEXT NOT NULL,
    first_seen REAL NOT NULL,
    last_seen REAL NOT NULL,
    PRIMARY KEY (robot_id, public_key)
)
"""

ALERTS = """
CREATE TABLE IF NOT EXISTS alert_meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS alert_rules (
    name TEXT PRIMARY KEY,
    text TEXT NOT NULL,
    created REAL NOT NULL,
    created_by TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS alert_alerts (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    rule TEXT NOT NULL,
    key TEXT NOT NULL,
    robot TEXT NOT NULL,
    entity TEXT NOT NULL,
    kind TEXT NOT NULL,
    status TEXT NOT NULL,
    text TEXT NOT NULL,
    event_id INTEGER,
    first REAL NOT NULL,
    last REAL NOT NULL,
    count INTEGER NOT NULL,
    state TEXT NOT NULL,
    fired_at REAL,
    level INTEGER NOT NULL DEFAULT 0,
    acked_by TEXT,
    acked_at REAL,
    resolved_at REAL,
    notified INTEGER NOT NULL DEFAULT 1
);
CREATE INDEX IF NOT EXISTS alert_alerts_key ON alert_alerts (key, state);
CREATE INDEX IF NOT EXISTS alert_alerts_state ON alert_alerts (state, id);
CREATE TABLE IF NOT EXISTS alert_outbox (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    alert_id INTEGER,
    rule TEXT NOT NULL,
    channel TEXT NOT NULL,
    purpose TEXT NOT NULL,
    payload TEXT NOT NULL,
    created REAL NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0,
    next_attempt REAL NOT NULL,
    state TEXT NOT NULL DEFAULT 'pending',
    last_error TEXT NOT NULL DEFAULT '',
    finished REAL
);
CREATE INDEX IF NOT EXISTS alert_outbox_due ON alert_outbox (state, next_attempt);
CREATE TABLE IF NOT EXISTS alert_unmatched (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time REAL NOT NULL,
    kind TEXT NOT NULL,
    robot TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS alert_unmatched_time ON alert_unmatched (time);
CREATE TABLE IF NOT EXISTS alert_rate (
    rule TEXT PRIMARY KEY,
    window_start REAL NOT NULL,
    sent INTEGER NOT NULL,
    suppressed INTEGER NOT NULL,
    examples TEXT NOT NULL DEFAULT '[]'
)
"""

PARTS = {"accounts": ACCOUNTS, "tokens": TOKENS, "robot_keys": ROBOT_KEYS, "alerts": ALERTS}
"""The parts of version 2, by the module that uses them."""

STATUS_HISTORY = """
CREATE TABLE IF NOT EXISTS status_changes (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    resource_id INTEGER NOT NULL,
    instance_id INTEGER NOT NULL,
    time REAL NOT NULL,
    status TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS status_changes_time ON status_changes (resource_id, time);
CREATE INDEX IF NOT EXISTS status_changes_entity ON status_changes
    (resource_id, instance_id, time)
"""
"""Version 3: each entity's and robot's status changes (:mod:`blackbox.station.status_history`)."""

MIGRATIONS: dict[int, tuple[str, ...]] = {
    1: (FLEET,),
    2: (ACCOUNTS, TOKENS, ROBOT_KEYS, ALERTS),
    3: (STATUS_HISTORY,),
}
"""The DDL that takes a database from version ``n - 1`` to ``n``."""


def ddl(text: str, dialect: str) -> list[str]:
    """The statements of ``text`` for ``dialect`` (``sqlite`` or ``postgresql``)."""
    statements = [s.strip() for s in text.split(";") if s.strip()]
    if dialect == "sqlite":
        return statements
    return [_postgres(s) for s in statements]


def _postgres(statement: str) -> str:
    s = re.sub(r"\bINTEGER PRIMARY KEY AUTOINCREMENT\b",
               "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY", statement)
    s = re.sub(r"\bINTEGER\b", "BIGINT", s)
    return re.sub(r"\bREAL\b", "DOUBLE PRECISION", s)


def apply(db: Connection, dialect: str, texts: tuple[str, ...]) -> None:
    for text in texts:
        for statement in ddl(text, dialect):
            db.execute(statement)


def ensure_part(database: Database, db: Connection, part: str) -> None:
    """Create the tables of ``part`` (see :data:`PARTS`) unless they exist (idempotent)."""
    apply(db, database.dialect, (PARTS[part],))
