"""The recorder always restarts: after a SIGKILL or a power cut at any moment of a log's life,
the next ``blackbox run --record`` on the same path starts and appends to the same log, and
nothing that was committed before is lost.

A power cut is simulated by copying the log file and its WAL (not the shared-memory index,
which does not survive a reboot) while a recorder is writing, as the disk held them at
that instant; a torn WAL tail is simulated by cutting bytes off the copied WAL.
"""

from __future__ import annotations

import contextlib
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from blackbox.model import Code, Observation, Resource
from blackbox.record import Recorder, Store
from blackbox.record.logfile import classify
from blackbox.record.settings import RecorderSettings
from blackbox.record.store import APPLICATION_ID, MIGRATIONS, SCHEMA_VERSION, LogEntry
from conftest import wait_for

BLACKBOX = [sys.executable, "-m", "blackbox"]


def committed(log: Path) -> dict[int, LogEntry]:
    """Every committed entry of ``log`` by id, read as the next start would see it: from a
    copy opened for writing, so a hot rollback journal is rolled back as a start would."""
    with tempfile.TemporaryDirectory() as scratch:
        for name in (log.name, f"{log.name}-wal", f"{log.name}-journal"):
            with contextlib.suppress(FileNotFoundError):
                shutil.copyfile(log.parent / name, Path(scratch) / name)
        with Store.open(Path(scratch) / log.name, check=False) as store:
            return {e.id: e for e in store.query()}


def first_commit_done(log: Path) -> bool:
    try:
        with Store.open(log, readonly=True, check=False) as store:
            return store.meta("progress") is not None
    except Exception:
        return False


def header(path: Path) -> tuple[int, int]:
    """``user_version`` and ``application_id`` as the main file's own bytes hold them."""
    head = path.read_bytes()[:100]
    return int.from_bytes(head[60:64], "big"), int.from_bytes(head[68:72], "big")


# ---- a new log's header is durable from creation ------------------------------------------------


def test_a_new_log_has_its_header_in_the_main_file_before_any_checkpoint(tmp_path: Path) -> None:
    log = tmp_path / "log.db"
    with Store.open(log) as store:
        store.append([(1.0, "blackbox_event", None, None, {"event": "start"})])
        # The WAL holds the commit; the main file alone must already say what it is.
        assert Path(f"{log}-wal").stat().st_size > 0
        assert header(log) == (SCHEMA_VERSION, APPLICATION_ID)
        assert store.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


# ---- classification reads through SQLite, WAL included -------------------------------------------


def legacy_log_with_header_in_wal(directory: Path) -> Path:
    """A log as blackbox created it before the header was made durable: created in WAL mode,
    so schema and application id sit in the WAL until the first checkpoint. The files are
    copied while the connection is open, as a SIGKILL leaves them."""
    live = directory / "live"
    live.mkdir()
    db = sqlite3.connect(live / "log.db", isolation_level=None)
    db.execute("PRAGMA auto_vacuum = INCREMENTAL")
    db.execute("PRAGMA journal_mode = WAL")
    db.execute("PRAGMA wal_autocheckpoint = 0")
    for step, migrate in enumerate(MIGRATIONS):
        db.execute("BEGIN IMMEDIATE")
        migrate(db)
        db.execute(f"PRAGMA user_version = {step + 1}")
        db.execute("COMMIT")
    db.execute("INSERT INTO entries (time, kind, payload) VALUES (5.0, 31, '{\"event\":\"x\"}')")
    crashed = directory / "crashed"
    crashed.mkdir()
    shutil.copy(live / "log.db", crashed / "log.db")
    shutil.copy(live / "log.db-wal", crashed / "log.db-wal")
    db.close()
    assert header(crashed / "log.db") == (0, 0), "the header is only in the WAL"
    return crashed / "log.db"


def test_a_log_whose_header_is_only_in_its_wal_is_recognised_and_appended_to(
        tmp_path: Path) -> None:
    log = legacy_log_with_header_in_wal(tmp_path)
    assert classify(log) == "health_log"
    rec = Recorder(RecorderSettings(log, commit_interval=0.05, snapshot=None), robot_id="r")
    rec.close()
    entries = committed(log)
    assert [e.payload["event"] for e in entries.values()] == ["x", "start", "stop"]


def test_a_foreign_database_with_a_wal_stays_foreign_and_untouched(tmp_path: Path) -> None:
    other = tmp_path / "other.db"
    db = sqlite3.connect(other, isolation_level=None)
    db.execute("PRAGMA journal_mode = WAL")
    db.execute("PRAGMA wal_autocheckpoint = 0")
    db.execute("PRAGMA application_id = 1234")
    db.execute("CREATE TABLE meta (key TEXT, value TEXT)")
    before = other.read_bytes(), Path(f"{other}-wal").read_bytes()
    assert classify(other) == "foreign"
    assert (other.read_bytes(), Path(f"{other}-wal").read_bytes()) == before
    db.close()
    text = tmp_path / "robot.yaml"
    text.write_text("robot: {id: r}\n" * 20)
    assert classify(text) == "foreign"


KILLED_WHILE_CREATING = """
import os, signal, sqlite3, sys
from blackbox.record.store import APPLICATION_ID, MIGRATIONS
db = sqlite3.connect(sys.argv[1], isolation_level=None)
db.execute("PRAGMA cache_size = 5")  # pages spill into the file before the commit
db.execute("BEGIN IMMEDIATE")
for migrate in MIGRATIONS:
    migrate(db)
db.execute(f"PRAGMA application_id = {APPLICATION_ID}")
db.executemany("INSERT INTO meta VALUES (?, ?)", [(str(i), "x" * 500) for i in range(200)])
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_log_killed_while_being_created_is_started_afresh(tmp_path: Path) -> None:
    """A SIGKILL inside the creating transaction leaves pages in the file and a hot
    journal that a read-only look cannot roll back; the journal says the file was empty."""
    log = tmp_path / "log.db"
    proc = subprocess.run([sys.executable, "-c", KILLED_WHILE_CREATING, str(log)])
    assert proc.returncode == -signal.SIGKILL
    assert log.stat().st_size > 0 and Path(f"{log}-journal").exists()
    assert classify(log) == "empty"
    rec = Recorder(RecorderSettings(log, commit_interval=0.05, snapshot=None), robot_id="r")
    rec.close()
    assert [e.payload["event"] for e in committed(log).values()] == ["start", "stop"]


# ---- SIGKILL of a real `blackbox run --record` ---------------------------------------------


def killed_run(log: Path, when: Callable[[subprocess.Popen[bytes]], None]) -> None:
    """Start ``blackbox run --record log`` in real time, wait for ``when``, SIGKILL it."""
    proc = subprocess.Popen([*BLACKBOX, "run", "--quiet", "--record", str(log)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        when(proc)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL, err.decode()


def as_soon_as_the_file_exists(log: Path) -> Callable[[subprocess.Popen[bytes]], None]:
    def wait(proc: subprocess.Popen[bytes]) -> None:
        deadline = time.monotonic() + 30
        while not log.exists():
            assert proc.poll() is None, "the black box exited before creating its log"
            assert time.monotonic() < deadline, f"{log} was never created"
            time.sleep(0.001)
    return wait


def after_first_commit(log: Path, then: float = 0.0) -> Callable[[subprocess.Popen[bytes]], None]:
    def wait(proc: subprocess.Popen[bytes]) -> None:
        assert wait_for(lambda: first_commit_done(log) or proc.poll() is not None, 30), \
            "the black box never committed"
        assert proc.poll() is None, "the black box exited"
        time.sleep(then)  # the run goes on writing; any moment will do
    return wait


MOMENTS: dict[str, Callable[[Path], Callable[[subprocess.Popen[bytes]], None]]] = {
    "first_second": as_soon_as_the_file_exists,
    "after_first_commit": after_first_commit,
    "mid_run": lambda log: after_first_commit(log, then=3.0),
}


@pytest.mark.slow
@pytest.mark.parametrize("moment", list(MOMENTS))
def test_after_a_sigkill_the_next_run_starts_and_appends(tmp_path: Path, moment: str) -> None:
    log = tmp_path / "log.db"
    killed_run(log, MOMENTS[moment](log))
    before = committed(log) if log.stat().st_size else {}

    again = subprocess.run([*BLACKBOX, "run", "--quiet", "--record", str(log),
                            "--duration", "1"], capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr

    after = committed(log)
    assert {i: after.get(i) for i in before} == before, "a committed entry was lost"
    def starts(entries: dict[int, LogEntry]) -> int:
        return sum(e.entity == "blackbox/recorder" and e.payload.get("event") == "start"
                   for e in entries.values())
    assert starts(after) == starts(before) + 1
    assert max(after) > max(before, default=0), "the new run appended"
    assert not list(tmp_path.glob("log.db.*-*")), "nothing was moved aside"


# ---- a power cut: the disk as it was at one instant -----------------------------------------


def writing_recorder(log: Path, stop: threading.Event) -> threading.Thread:
    """A recorder committing a change of 20 channels every 10 ms until ``stop``."""
    def run() -> None:
        rec = Recorder(RecorderSettings(log, commit_interval=0.02, snapshot=None), robot_id="p")
        resources = [Resource(topic=f"/t{k}") for k in range(20)]
        seq = 0
        try:
            while not stop.is_set():
                code = Code.GENERAL_OK if (seq // 20) % 2 else Code.NO_STATE_FITS
                rec.on_observations(float(seq), [
                    Observation(float(seq), "hz", r, code, values={"seq": seq}) for r in resources])
                seq += 1
                time.sleep(0.01)
        finally:
            rec.close()
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def power_cut_copy(log: Path, target: Path, wal_cut: int = 0) -> Path:
    """The log and its WAL as the disk held them now (``wal_cut`` bytes of the WAL's tail
    not yet on the medium)."""
    target.mkdir()
    # In the order that gives a state the disk really passes through: a rollback journal
    # (only while the log is created) goes before the pages it protects and is deleted
    # after them; the WAL is only appended to (no checkpoint runs in so small a log).
    journal = Path(f"{log}-journal")
    with contextlib.suppress(FileNotFoundError):
        shutil.copy(journal, target / journal.name)
    shutil.copy(log, target / log.name)
    wal = Path(f"{log}-wal")
    wal_bytes = wal.read_bytes() if wal.exists() else b""
    if wal_bytes:
        (target / f"{log.name}-wal").write_bytes(wal_bytes[:max(0, len(wal_bytes) - wal_cut)])
    return target / log.name


@pytest.mark.parametrize("wal_cut", [0, 1000])
def test_after_a_power_cut_the_recorder_starts_on_the_same_log(tmp_path: Path,
                                                               wal_cut: int) -> None:
    log = tmp_path / "live" / "log.db"
    log.parent.mkdir()
    stop = threading.Event()
    writer = writing_recorder(log, stop)
    copies: list[Path] = []
    try:
        assert wait_for(log.exists, 10), "the recorder never created its log"
        copies.append(power_cut_copy(log, tmp_path / "at_creation", wal_cut))
        assert wait_for(lambda: first_commit_done(log), 10), "the recorder never committed"
        copies.append(power_cut_copy(log, tmp_path / "after_first_commit", wal_cut))
        assert wait_for(lambda: Path(f"{log}-wal").stat().st_size > 200_000, 20)
        copies.append(power_cut_copy(log, tmp_path / "mid_run", wal_cut))
    finally:
        stop.set()
        writer.join(30)
    for copy in copies:
        kind = classify(copy)
        assert kind in ("health_log", "empty"), \
            f"{copy.parent.name}: {kind} ({sorted(p.name for p in copy.parent.iterdir())})"
        before = committed(copy) if kind == "health_log" else {}
        rec = Recorder(RecorderSettings(copy, commit_interval=0.05, snapshot=None), robot_id="p")
        rec.close()
        after = committed(copy)
        assert {i: after.get(i) for i in before} == before, f"{copy.parent.name}: lost entries"
        assert [e.payload["event"] for e in after.values()
                if e.kind == "blackbox_event"][-2:] == ["start", "stop"], "appended"
        assert not list(copy.parent.glob("log.db.*-*")), "nothing was moved aside"
