"""Crash safety: SIGKILL during heavy writing, 20 times; a full disk; the log survives."""

from __future__ import annotations

import os
import random
import sqlite3
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from blackbox.model import BlackBoxEvent, Code, Observation, Resource
from blackbox.record import Recorder, Store
from blackbox.record.settings import RecorderSettings
from blackbox.record.store import Row
from crash_support import sigkill_after

COMMIT = 0.25
# Writing one commit interval's rows takes part of the next interval; scheduling on a
# two-core machine adds a little more. The loss bound below is one interval plus this,
# plus how late the writer itself woke up in its last second (a loaded machine delays the
# commit thread as much as the loop that hands it rows: that is the machine, not the log).
MARGIN = 0.25
PACE = 0.05

WRITER = """
import os, sys, time
from blackbox.model import Code, Observation, Resource
from blackbox.record import Recorder
from blackbox.record.settings import RecorderSettings
run = int(sys.argv[2])
rec = Recorder(RecorderSettings(sys.argv[1], commit_interval=float(sys.argv[3]), snapshot=None),
               robot_id="crash")
pace = float(sys.argv[5])
progress = os.open(sys.argv[4], os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_TRUNC)
resources = [Resource(topic=f"/t{k}") for k in range(50)]
print("ready", flush=True)
seq = 0
late = 0.0
while True:  # 2,000 observations a second, each a state change, so each is logged
    batch = []
    for _ in range(100):
        code = Code.GENERAL_OK if (seq // 50) % 2 else Code.NO_STATE_FITS
        batch.append(Observation(time.time(), "hz", resources[seq % 50], code,
                                 values={"run": run, "seq": seq}))
        seq += 1
    rec.on_observations(time.time(), batch)
    # The page cache keeps this line through a SIGKILL: what was handed over, and when.
    os.write(progress, f"{batch[-1].time!r} {late!r}\\n".encode())
    slept = time.monotonic()
    time.sleep(pace)
    late = time.monotonic() - slept - pace
"""


def _handed_over(progress: Path) -> tuple[float, float]:
    """The time of the last observation handed to the recorder before the kill, and how
    late the writer's loop woke up at most in the second before it."""
    lines = [line.split() for line in progress.read_text().splitlines() if line.count(" ") == 1]
    times = [(float(t), float(late)) for t, late in lines]
    last = times[-1][0]
    return last, max(late for t, late in times if t >= last - 1.0)


def _env() -> dict[str, str]:
    src = str(Path(__file__).resolve().parent.parent / "src")
    return {**os.environ, "PYTHONPATH": src + os.pathsep + os.environ.get("PYTHONPATH", "")}


@pytest.mark.slow
def test_sigkill_during_heavy_writing_loses_at_most_one_commit_interval(tmp_path: Path) -> None:
    log = tmp_path / "log.db"
    rng = random.Random(5)
    runs = 20
    for run in range(runs):
        progress = tmp_path / f"progress-{run}"
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(log), str(run), str(COMMIT),
                                 str(progress), str(PACE)], stdout=subprocess.PIPE, env=_env())

        def ready(proc: subprocess.Popen[bytes] = proc) -> None:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == b"ready"

        sigkill_after(proc, ready, rng.uniform(0.4, 1.2))
        handed_at, late = _handed_over(progress)

        with Store.open(log) as store:  # opening replays the WAL, as the next start would
            assert store.integrity_check() == "ok"
            # Through the store: logged observations are in frames as well as in entries.
            mine = sorted((e for e in store.query(kinds=["observation", "exceedance"])
                           if e.payload["values"].get("run") == run), key=lambda e: e.id)
            assert mine, f"run {run}: nothing committed"
            lost = handed_at - max(e.time for e in mine)
            assert lost <= COMMIT + MARGIN + late, (
                f"run {run}: lost the last {lost:.3f} s (the writer woke up {late:.3f} s late)")
            seqs = [e.payload["values"]["seq"] for e in mine]
            assert seqs == list(range(len(seqs))), "a committed prefix, without holes"

    with Store.open(log, readonly=True) as store:
        starts = [e for e in store.query(kinds=["blackbox_event"])
                  if e.payload.get("event") == "start"]
        assert len(starts) == runs  # every start appended to the same log
        ids = [e.id for e in store.query()]
        assert len(ids) == len(set(ids))


class FullDisk:
    """A disk the test fills and empties again; ``variant`` says which kind ran.

    ``tmpfs``: a real 8 MiB tmpfs, filled with a file until writes fail with ENOSPC, so
    SQLite itself runs into the full disk (needs root to mount, as in CI).
    ``injected``: where mounting is not allowed a size-limited filesystem cannot run, so
    while "full" the store's write boundary (``Store._insert``, inside the transaction
    that ``Store.append`` opens and rolls back) raises the error SQLite raises for
    SQLITE_FULL on ENOSPC. Everything above that boundary (transaction rollback, the
    recorder's backlog, self-monitoring, reconnecting, resuming) runs for real.
    """

    def __init__(self, variant: str, directory: Path) -> None:
        self.variant = variant
        self.directory = directory
        self.full = False
        self._filler = directory / "filler"

    def fill(self) -> None:
        self.full = True
        if self.variant == "tmpfs":
            chunk = b"\xff" * 65536
            with self._filler.open("wb") as fh:
                try:
                    while True:
                        fh.write(chunk)
                        fh.flush()
                except OSError:
                    pass

    def free(self) -> None:
        self.full = False
        if self.variant == "tmpfs":
            self._filler.unlink()


@pytest.fixture(params=["tmpfs", "injected"])
def full_disk(request: pytest.FixtureRequest, tmp_path: Path,
              monkeypatch: pytest.MonkeyPatch) -> Iterator[FullDisk]:
    if request.param == "injected":
        disk = FullDisk("injected", tmp_path)
        insert = Store._insert

        def insert_unless_full(self: Store, rows: Sequence[Row], *args: Any) -> list[int]:
            if disk.full:
                raise sqlite3.OperationalError("database or disk is full")
            return insert(self, rows, *args)

        monkeypatch.setattr(Store, "_insert", insert_unless_full)
        yield disk
        return
    mnt = tmp_path / "small"
    mnt.mkdir()
    result = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", f"bb-{uuid.uuid4().hex[:8]}",
                             str(mnt)], capture_output=True, text=True)
    if result.returncode != 0:
        pytest.skip(f"cannot mount a size-limited tmpfs here ({result.stderr.strip()}); "
                    "the injected variant covers the behaviour")
    try:
        yield FullDisk("tmpfs", mnt)
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_full_disk_is_reported_observation_continues_and_writing_resumes(
        full_disk: FullDisk) -> None:
    log = full_disk.directory / "log.db"
    events: list[BlackBoxEvent] = []
    rec = Recorder(RecorderSettings(log, commit_interval=0.05, retry_interval=0.05, snapshot=None,
                                    queue_limit=1_000_000),
                   robot_id="r1", on_self_event=events.append)
    t = [1_700_000_000.0]
    batches = [0]

    def observe(n: int = 200) -> None:
        code = Code.NO_STATE_FITS if batches[0] % 2 else Code.GENERAL_OK
        batches[0] += 1
        batch = []
        for k in range(n):  # each a state change of its channel, ~300 bytes of payload
            t[0] += 0.001
            batch.append(Observation(t[0], "hz", Resource(topic=f"/t{k}"), code,
                                     message="x" * 250))
        rec.on_observations(t[0], batch)  # must never raise or block

    observe()
    deadline = time.monotonic() + 20
    while rec.written < 200:
        assert time.monotonic() < deadline
        time.sleep(0.02)

    full_disk.fill()
    deadline = time.monotonic() + 20
    while not rec.failing:
        assert time.monotonic() < deadline, "the full disk was never noticed"
        observe()
        time.sleep(0.02)
    observe()  # delivers the self-event on this (the pipeline's) thread
    full_since = t[0]
    health = rec.health()
    assert health.code == Code.GENERAL_ERROR
    assert health.resource == Resource(node="/blackbox/recorder")
    assert "full" in health.message
    assert [(e.kind, e.component) for e in events] == [("storage_error", "blackbox/recorder")]
    for _ in range(10):
        observe()
    full_until = t[0]

    full_disk.free()  # space returns
    deadline = time.monotonic() + 20
    while rec.failing:
        assert time.monotonic() < deadline, "writing did not resume"
        time.sleep(0.02)
    observe()
    assert [e.kind for e in events] == ["storage_error", "storage_resumed"]
    assert rec.health().code == Code.GENERAL_OK
    rec.close()

    with Store.open(log, readonly=True) as store:
        assert store.integrity_check() == "ok"
        own = [e.payload["event"] for e in store.query(kinds=["blackbox_event"])]
        assert own[:1] == ["start"] and "storage_error" in own and "storage_resumed" in own
        # Nothing was dropped: the backlog held what arrived while the disk was full.
        assert rec.dropped == 0
        changes = store.count("observation") + store.count("exceedance")
        assert changes == 200 * batches[0]
        assert store.count() == rec.written
        during = list(store.query(start=full_since, end=full_until, kinds=["exceedance"]))
        assert len(during) >= 200 * 5
