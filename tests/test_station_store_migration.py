"""A station database made by an earlier version keeps opening, with everything in it.

``tests/data/station-v1.db.gz`` was written by the station before its storage was split
(schema version 1: fleet tables by the store, accounts, tokens, robot keys and alerts
created by their modules on their own). Opening it migrates it to the current version
without losing a row, and every part of the station can use it as before.
"""

from __future__ import annotations

import gzip
import shutil
import sqlite3
from pathlib import Path

from argon2 import PasswordHasher

from blackbox.station.alerts.db import AlertDB
from blackbox.station.auth import Auth
from blackbox.station.enrolment import RobotKeys
from blackbox.station.schema import SCHEMA_VERSION
from blackbox.station.store import StationStore
from blackbox.station.tokens import ApiTokens

DATA = Path(__file__).parent / "data" / "station-v1.db.gz"
TOKEN = "bbt_1_GxvLPVUw8CL2C00C_DM7aM1_eGAltbygx_JivOFVr_M"
T = 1_790_000_000.0


def v1_file(tmp_path: Path) -> Path:
    path = tmp_path / "station.db"
    with gzip.open(DATA, "rb") as src, path.open("wb") as dst:
        shutil.copyfileobj(src, dst)
    return path


def test_a_version_1_file_opens_migrated_with_its_fleet_data(tmp_path: Path) -> None:
    path = v1_file(tmp_path)
    with sqlite3.connect(path) as raw:
        assert raw.execute("SELECT value FROM meta WHERE key = 'schema_version'"
                           ).fetchone()[0] == "1"
    store = StationStore(path, clock=lambda: T)
    try:
        [robot] = store.fleet()
        assert (robot.robot_id, robot.diagnosis, robot.unacknowledged) == ("old-robot",
                                                                           ("/camera",), 1)
        assert [e.kind for e in store.events().events] == ["acknowledgement", "exceedance",
                                                           "failure"]
        assert len(store.series(robot.resource_id, 10, since=T - 100)) == 5
        [req] = store.log_requests()
        assert [e.id for e in store.log_entries(req.id)] == [7]
        assert store.ibit_runs()[0].report == ("rate 0 Hz",)
        store.add_event(robot.resource_id, T, "failure", dedup="id:boot1-1")  # known id
        store.add_event(robot.resource_id, T, "failure", dedup="id:boot1-3")
        assert store.flush() and store.count_events(kinds=["failure"]) == 2
    finally:
        store.close()
    with sqlite3.connect(path) as raw:
        assert raw.execute("SELECT value FROM meta WHERE key = 'schema_version'"
                           ).fetchone()[0] == str(SCHEMA_VERSION)


def test_a_version_1_file_keeps_its_accounts_tokens_keys_and_alert_rules(
        tmp_path: Path) -> None:
    path = v1_file(tmp_path)
    StationStore(path).close()
    auth = Auth(path, hasher=PasswordHasher(time_cost=1, memory_cost=1024, parallelism=1))
    try:
        assert [u.name for u in auth.users()] == ["olga"]
        login = auth.log_in("olga", "correct horse battery staple 42", "127.0.0.1")
        assert login.session is not None
        user = ApiTokens(path, auth, clock=lambda: T).user_of(TOKEN)
        assert user is not None and user.name == "olga"
    finally:
        auth.close()
    keys = RobotKeys(path)
    assert [r.robot_id for r in keys.robots()] == ["old-robot"]
    keys.close()
    alerts = AlertDB(path)
    with alerts.reading() as db:
        assert db.execute("SELECT name FROM alert_rules").fetchall() == [("cams",)]
    alerts.close()
