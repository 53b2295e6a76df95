"""A real, throwaway PostgreSQL cluster for the tests of the PostgreSQL station store.

``postgres`` (session-scoped: one cluster per pytest-xdist worker, each on its own free port
and directory) starts Debian's PostgreSQL with ``scripts/postgres-cluster.sh`` and removes it
afterwards; ``postgres_url`` gives every test a database of its own in that cluster. Tests
that stop and start the server (the database going away) use :func:`own_cluster`.
"""

from __future__ import annotations

import itertools
import os
import shutil
import socket
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "postgres-cluster.sh"


def postgres_available() -> str | None:
    """Why PostgreSQL tests cannot run here, or ``None`` when they can."""
    if not list(Path("/usr/lib/postgresql").glob("*/bin/initdb")):
        return "PostgreSQL is not installed (scripts/install-system-deps.sh)"
    try:
        import psycopg  # noqa: F401
    except ImportError:
        return "psycopg is not installed (pip install -e '.[postgresql]')"
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Cluster:
    """One running cluster: its directory, port and the URL of its ``postgres`` database."""

    directory: Path
    port: int
    url: str
    _names: itertools.count[int]

    def run(self, *args: str) -> None:
        done = subprocess.run([str(SCRIPT), *args], capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 0, f"postgres-cluster.sh {args[0]}: {done.stderr}"

    def stop(self) -> None:
        self.run("stop", str(self.directory))

    def start(self) -> None:
        self.run("restart", str(self.directory))

    def database_url(self, name: str) -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/{name}"

    def create_database(self, tablespace: str | None = None) -> str:
        """A new empty database; its URL."""
        import psycopg

        name = f"t{next(self._names)}_{uuid.uuid4().hex[:8]}"
        with psycopg.connect(self.url, autocommit=True) as db:
            db.execute(f"CREATE DATABASE {name}" +
                       (f" TABLESPACE {tablespace}" if tablespace else ""))
        return self.database_url(name)

    def sql(self, statement: str) -> None:
        import psycopg

        with psycopg.connect(self.url, autocommit=True) as db:
            db.execute(statement)


@contextmanager
def own_cluster() -> Iterator[Cluster]:
    """A cluster that exists for the block only (removed afterwards, also on failure).

    Its directory is under /tmp (not pytest's 0700 tmp_path): the server runs as the
    ``postgres`` user and must reach it."""
    reason = postgres_available()
    if reason:
        pytest.skip(reason)
    directory = Path(tempfile.mkdtemp(prefix="bb-pg-"))
    port = free_port()
    done = subprocess.run([str(SCRIPT), "start", str(directory), str(port)],
                          capture_output=True, text=True, timeout=180)
    if done.returncode != 0:
        shutil.rmtree(directory, ignore_errors=True)
        raise AssertionError(f"cannot start PostgreSQL: {done.stderr}")
    cluster = Cluster(directory, port, done.stdout.strip(), itertools.count())
    try:
        yield cluster
    finally:
        subprocess.run([str(SCRIPT), "remove", str(directory)], capture_output=True,
                       timeout=120)


@pytest.fixture(scope="session")
def postgres() -> Iterator[Cluster]:
    """One PostgreSQL cluster per test process (xdist worker)."""
    with own_cluster() as cluster:
        yield cluster


@pytest.fixture
def postgres_url(postgres: Cluster) -> str:
    """A fresh database of its own for one test."""
    return postgres.create_database()


def is_root() -> bool:
    return os.geteuid() == 0
