"""Stations on PostgreSQL: several station processes share one database, and a database that
goes away, comes back or fills up costs the operator nothing already stored.

Everything is real: ``blackbox station`` processes, scripted black boxes publishing over
Cyclone DDS on loopback (``tests/dds_blackbox_driver.py``), and PostgreSQL clusters of
Debian's package started for each test by ``scripts/postgres-cluster.sh``.
"""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

from blackbox.station.store import StationStore, UnknownRobot
from conftest import wait_until
from isolation import fresh_domain
from postgres_support import Cluster, is_root, own_cluster
from station_support import ScriptedBlackBox, dds_env, station_key_for_tests

pytestmark = [pytest.mark.dds, pytest.mark.slow]

BURST = 500
"""Fault/recovery pairs in one burst: 1,000 failure and rectification events."""
PASSWORD = "station password 1"


class StationProcess:
    """``blackbox station`` on ``database``, following DDS ``domain``, serving on a free port,
    with the tests' station key (robots answer its log requests: gaps are backfilled)."""

    def __init__(self, database: str, domain: int, directory: Path, name: str) -> None:
        self.ready = directory / f"{name}.url"
        self.log = directory / f"{name}.log"
        self._log = self.log.open("wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "blackbox", "station", "--db", database,
             "--bind", "127.0.0.1:0", "--domain", str(domain), "--stale-after", "30",
             "--ready-file", str(self.ready), "--key", str(station_key_for_tests())],
            env=dds_env(), stdout=subprocess.DEVNULL, stderr=self._log)
        wait_until(lambda: self.ready.exists() or self.proc.poll() is not None,
                   f"station {name} to serve", timeout=90)
        assert self.proc.poll() is None, self.stderr()
        self.url = self.ready.read_text().strip()

    def stderr(self) -> str:
        return self.log.read_text(errors="replace")

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(timeout=30)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.kill()
        self._log.close()


@pytest.fixture
def stations(tmp_path: Path) -> Iterator[list[StationProcess]]:
    started: list[StationProcess] = []
    yield started
    for s in started:
        s.stop()


@pytest.fixture
def boxes() -> Iterator[list[ScriptedBlackBox]]:
    started: list[ScriptedBlackBox] = []
    yield started
    for b in started:
        b.stop()


def add_user(database: str) -> None:
    done = subprocess.run([sys.executable, "-m", "blackbox", "station", "user", "add", "olga",
                           "--role", "admin", "--db", database], input=PASSWORD + "\n",
                          capture_output=True, text=True, timeout=60, env=dds_env())
    assert done.returncode == 0, done.stderr


def log_in(url: str) -> httpx.Client:
    client = httpx.Client(base_url=url, timeout=30)
    form = client.get("/login")
    match = re.search(r'name="login_token" value="([^"]+)"', form.text)
    assert match is not None, form.text[:500]
    reply = client.post("/login", data={"username": "olga", "password": PASSWORD,
                                        "login_token": match.group(1)})
    assert reply.status_code == 303 and client.cookies.get("bb_session"), reply.text[:300]
    return client


def counts(store: StationStore, robot: str) -> dict[str, int]:
    try:
        return {k: store.count_events(robot, kinds=[k]) for k in ("failure", "rectification")}
    except UnknownRobot:
        return {}


def duplicates(cluster_url: str) -> int:
    """Events stored more than once under one identity, counted by the database itself."""
    import psycopg

    with psycopg.connect(cluster_url) as db:
        row = db.execute("SELECT count(*) - count(DISTINCT (resource_id, dedup)) "
                         "FROM events").fetchone()
    assert row is not None
    return int(row[0])


def send_later(box: ScriptedBlackBox, command: str) -> None:
    """Send ``command`` without waiting for its answer (read it with :func:`answered`)."""
    assert box.proc.stdin is not None
    box.proc.stdin.write(command + "\n")
    box.proc.stdin.flush()


def answered(box: ScriptedBlackBox, command: str) -> None:
    assert box.proc.stdout is not None
    assert box.proc.stdout.readline().strip() == f"done {command}"


def test_two_stations_share_one_postgresql_and_one_killed_mid_burst_loses_nothing(
        tmp_path: Path, stations: list[StationProcess],
        boxes: list[ScriptedBlackBox]) -> None:
    with own_cluster() as cluster:
        database = cluster.create_database()
        add_user(database)
        domain = fresh_domain()
        a = StationProcess(database, domain, tmp_path, "a")
        stations.append(a)
        b = StationProcess(database, domain, tmp_path, "b")
        stations.append(b)
        browser = log_in(a.url)
        # The robot keeps a log: what DDS fails to deliver is fetched from it (by number).
        box = ScriptedBlackBox("burst", domain, store=tmp_path / "robot.db")
        boxes.append(box)
        box.send("ok")
        store = StationStore(database)
        try:
            wait_until(lambda: "burst" in {r.robot_id for r in store.fleet()},
                       "the robot in the shared database", timeout=60)
            send_later(box, f"burst {BURST}")
            wait_until(lambda: counts(store, "burst").get("failure", 0) > 0,
                       "the first events of the burst stored", timeout=60)
            a.kill()  # mid-burst: station a dies with whatever it had not written
            stored_at_kill = sum(counts(store, "burst").values())
            answered(box, f"burst {BURST}")
            try:
                wait_until(lambda: counts(store, "burst") == {"failure": BURST,
                                                              "rectification": BURST},
                           f"station b to store all {BURST} failures and rectifications",
                           timeout=120)
            except AssertionError as exc:
                raise AssertionError(f"{exc}: {counts(store, 'burst')} stored; "
                                     f"station b said: {b.stderr()[-2000:]}") from None
            # On a quiet machine both stations may hold the whole burst before the kill
            # lands (stored_at_kill == 2 * BURST); the kill is then after the burst, and what
            # is checked is that the survivor carries on with nothing lost or doubled.
            assert stored_at_kill <= 2 * BURST
            assert duplicates(database) == 0
            # The session made on station a is valid on station b: one set of accounts.
            page = httpx.get(b.url, cookies={"bb_session": browser.cookies["bb_session"]},
                             follow_redirects=False, timeout=30)
            assert page.status_code == 200 and "burst" in page.text
            assert b.proc.poll() is None
        finally:
            browser.close()
            store.close()


def test_the_database_going_away_and_coming_back_loses_nothing_and_is_reported(
        tmp_path: Path, stations: list[StationProcess],
        boxes: list[ScriptedBlackBox]) -> None:
    with own_cluster() as cluster:
        database = cluster.create_database()
        add_user(database)
        domain = fresh_domain()
        station = StationProcess(database, domain, tmp_path, "station")
        stations.append(station)
        browser = log_in(station.url)
        box = ScriptedBlackBox("wanderer", domain, store=tmp_path / "robot.db")
        boxes.append(box)
        box.send("ok")
        box.send("fault")
        box.send("ok")
        store = StationStore(database)
        try:
            wait_until(lambda: counts(store, "wanderer") == {"failure": 1, "rectification": 1},
                       "the first fault and recovery stored", timeout=60)
        finally:
            store.close()
        cluster.stop()  # the database goes away
        for _ in range(3):
            box.send("fault")
            box.send("ok")
        page = browser.get("/", follow_redirects=False)
        assert page.status_code == 503 and "cannot" in page.text  # said, not a crash
        wait_until(lambda: "cannot write" in station.stderr(),
                   "the station's log to tell the write failed", timeout=30)
        # still serving: the log-in page to someone new, the page's own files
        assert httpx.get(station.url + "login", timeout=30).status_code == 200
        assert browser.get("/static/station.css").status_code == 200
        cluster.start()  # ... and comes back
        store = StationStore(database)
        try:
            wait_until(lambda: counts(store, "wanderer") == {"failure": 4, "rectification": 4},
                       "the events heard while the database was away", timeout=60)
            assert duplicates(database) == 0
            page = wait_until(lambda: (r := browser.get("/")).status_code == 200 and r,
                              "the fleet page to answer again", timeout=30)
            assert "writable again" in page.text or "cannot write" in page.text
        finally:
            store.close()
            browser.close()
        assert station.proc.poll() is None


@contextmanager
def small_tablespace(cluster: Cluster, directory: Path) -> Iterator[tuple[str, Path]]:
    """A 32 MiB tmpfs holding a PostgreSQL tablespace (its name and mount point). The
    cluster's own files and write-ahead log stay on the big disk, as a careful deployment
    would have them; only the station's tables can run out of room."""
    if not is_root():
        pytest.skip("mounting a small tmpfs needs root (as in CI)")
    mount = directory / "small"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=32m",
                           f"pg-{uuid.uuid4().hex[:8]}", str(mount)],
                          capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        (mount / "pg").mkdir()
        shutil.chown(mount / "pg", "postgres")
        name = f"small_{uuid.uuid4().hex[:8]}"
        cluster.sql(f"CREATE TABLESPACE {name} LOCATION '{mount / 'pg'}'")
        yield name, mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True, timeout=30)


def fill(mount: Path) -> Path:
    """Fill the file system at ``mount`` to the last byte; the filler's path."""
    filler = mount / "filler"
    with filler.open("wb", buffering=0) as fh, pytest.raises(OSError):
        while True:
            fh.write(b"\0" * 65536)
    return filler


def test_a_full_postgresql_disk_is_reported_and_nothing_stored_or_heard_is_lost() -> None:
    with own_cluster() as cluster, small_tablespace(cluster, cluster.directory) as (
            tablespace, mount):
        database = cluster.create_database(tablespace)
        store = StationStore(database)
        try:
            rid = 4711
            store.put_robot_id(rid, "tug-9")
            store.heard(rid, 1.0)
            for i in range(200):
                store.add_event(rid, 1.0 + i, "failure", dedup=f"id:b-{i}", entity="/x")
            assert store.flush()
            filler = fill(mount)
            for i in range(200, 5_200):  # more than the pages left can hold
                store.add_event(rid, 1.0 + i, "failure", dedup=f"id:b-{i}", entity="/x",
                                text="a long enough text to need new pages " * 40)
            assert not store.flush(force=True)
            [problem] = [p for p in store.problems() if p.source == "store"]
            assert "No space left on device" in problem.message \
                or "could not extend" in problem.message
            assert "kept in memory, retried" in problem.message
            assert store.count_events(rid) == 200  # what was stored is still there, readable
            assert store.pending > 0
            filler.unlink()  # room again
            wait_until(lambda: store.flush(force=True), "the queued events to be written",
                       timeout=60)
            assert store.count_events(rid) == 5_200
            assert [p.source for p in store.problems()][:1] == ["store-recovered"]
        finally:
            store.close()
