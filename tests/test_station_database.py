"""Where the station's database is, as ``blackbox station --db`` takes it, and what a wrong
one says: one line, exit code 2, never a traceback or a password."""

from __future__ import annotations

import subprocess
import sys

import pytest

from blackbox.station.database import PostgresDatabase, SqliteDatabase, open_database, postgres_sql


@pytest.mark.parametrize(("location", "kind", "shown"), [
    ("station.db", SqliteDatabase, "station.db"),
    ("sqlite:///station.db", SqliteDatabase, "station.db"),
    ("sqlite:////var/lib/blackbox/station.db", SqliteDatabase, "/var/lib/blackbox/station.db"),
    (":memory:", SqliteDatabase, ":memory:"),
    ("postgresql://station@db.example:5432/blackbox", PostgresDatabase,
     "postgresql://station@db.example:5432/blackbox"),
    ("postgres://station:hunter2@db.example/blackbox", PostgresDatabase,
     "postgres://station:***@db.example/blackbox"),
])
def test_a_location_names_its_engine_and_is_shown_without_a_password(
        location: str, kind: type, shown: str) -> None:
    database = open_database(location)
    assert isinstance(database, kind) and database.describe() == shown


def test_the_shared_sql_is_translated_to_psycopg_placeholders() -> None:
    assert postgres_sql("SELECT (k - 1) % ? FROM t WHERE a = ? AND b LIKE 'x%'") == \
        "SELECT (k - 1) %% %s FROM t WHERE a = %s AND b LIKE 'x%%'"


def test_an_unreachable_postgresql_is_one_line_and_exit_2() -> None:
    done = subprocess.run([sys.executable, "-m", "blackbox", "station", "user", "list", "--db",
                           "postgresql://postgres:hunter2@127.0.0.1:1/blackbox"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert "cannot" in done.stderr and "hunter2" not in done.stderr
