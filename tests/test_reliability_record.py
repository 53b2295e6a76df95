"""What a flight recorder must never do (issue 13): destroy files it did not write, escape
its directories, leave half-written snapshots, take bad paths or arguments silently."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from blackbox.events import MessageArrival, TopicSchema
from blackbox.model import BlackBoxEvent, Code, Diagnosis, Observation, Resource, State
from blackbox.output.jsonlines import JsonLinesSink, read_records
from blackbox.pipeline import Pipeline
from blackbox.record import Recorder, SnapshotConfig, Store
from blackbox.record.logfile import RecordPathError, safe_name
from blackbox.record.settings import RecorderSettings, SnapshotSettings
from blackbox.record.snapshot import WRITERS
from blackbox.sources.memory import MemorySource

T0 = 1_700_000_000.0
BLACKBOX = [sys.executable, "-m", "blackbox"]
STRING = TopicSchema("/chatter", "std_msgs/String", "ros1", "string data",
                     "992ce8a1687cec8c8bd883ec73ca41d1")
CAM = Resource(topic="/usb_cam/image_raw")


def blackbox(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*BLACKBOX, *args], capture_output=True, text=True, timeout=120,
                          cwd=cwd)


def faulty_run(rec: Recorder, now: list[float], faults: int, size: int = 2000) -> None:
    """``faults`` snapshots of 10 Hz chatter: a fault every 10 s, each a snapshot."""
    payload = struct.pack("<I", size) + b"x" * size
    for i in range(faults * 100):
        t = T0 + i * 0.1
        now[0] = t
        rec.on_message(MessageArrival(t, "/chatter", "/talker", len(payload),
                                      raw=lambda: payload))
        if i % 10 == 0:
            bad = (i // 10) % 10 == 3
            code = Code.NO_STATE_FITS if bad else Code.GENERAL_OK
            rec.on_observations(t, [Observation(t, "hz", CAM, code,
                                                () if bad else (State(1, "ok"),))])


def snapshot_settings(path: Path, **changes: object) -> RecorderSettings:
    snap = SnapshotSettings(SnapshotConfig(before=1.0, after=0.5), format="ros1", cooldown=0.0)
    return RecorderSettings(path, commit_interval=0.05, retention_interval=0.0,
                            retry_interval=0.05, snapshot=snap).replace(**changes)


# ---- retention ----------------------------------------------------------------------------


def test_retention_deletes_its_own_snapshots_never_a_users_file(tmp_path: Path) -> None:
    shared = tmp_path / "shared"
    shared.mkdir()
    user = shared / "field-trial.bag"  # older than anything, same suffix, over the budget
    user.write_bytes(b"precious" * 4000)
    os.utime(user, (1000, 1000))
    settings = snapshot_settings(tmp_path / "log.db", budget_bytes=400_000)
    settings = settings.replace(snapshot=SnapshotSettings(
        settings.snapshot.ring, format="ros1", cooldown=0.0, directory=shared, share=0.1))
    now = [T0]
    rec = Recorder(settings, robot_id="r1", clock=lambda: now[0],
                   schema_lookup={"/chatter": STRING}.get)
    faulty_run(rec, now, faults=8)
    rec.close()
    assert user.read_bytes() == b"precious" * 4000
    with Store.open(tmp_path / "log.db", readonly=True) as store:
        deleted = [n for e in store.query(kinds=["blackbox_event"])
                   if e.payload.get("event") == "snapshots_deleted" for n in e.payload["files"]]
        ours = store.snapshot_files()
    assert deleted, "the budget (40 kB) forced retention to delete snapshots"
    assert "field-trial.bag" not in deleted
    assert sorted(p.name for p in shared.iterdir()) == sorted(["field-trial.bag", *ours])


# ---- identifiers that become paths ---------------------------------------------------------


def test_a_robot_id_cannot_put_snapshots_outside_their_directory(tmp_path: Path) -> None:
    (tmp_path / "deep" / "er").mkdir(parents=True)
    log = tmp_path / "deep" / "er" / "log.db"
    now = [T0]
    rec = Recorder(snapshot_settings(log), robot_id="../../x", clock=lambda: now[0],
                   schema_lookup={"/chatter": STRING}.get)
    faulty_run(rec, now, faults=1)
    rec.close()
    snapshots = Path(f"{log}.snapshots")
    written = [p.name for p in snapshots.iterdir()]
    assert len(written) == 1 and written[0].startswith("x-") and written[0].endswith(".bag")
    assert len(list(tmp_path.rglob("*.bag"))) == 1 and \
        all(p.parent == snapshots for p in tmp_path.rglob("*.bag"))
    assert safe_name("../../x") == "x" and safe_name("a/b c") == "a_b_c"
    assert safe_name("..") == "robot" and "/" not in safe_name("/etc/passwd")


# ---- snapshots on a full disk --------------------------------------------------------------


def test_a_snapshot_failing_on_a_full_disk_leaves_no_file_and_is_retried(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The bag writer is the real one; ENOSPC is raised from inside it after it has created
    and partly written its file, as a full disk does (mounting a tiny tmpfs needs root;
    tests/test_record_crash.py covers a real one for the log)."""
    real = WRITERS["ros1"]
    full = [2]  # the first two attempts hit a full disk

    def bag_on_full_disk(messages, schemas, path):  # type: ignore[no-untyped-def]
        if full[0]:
            full[0] -= 1
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"partial")
            raise OSError(28, "No space left on device")
        return real(messages, schemas, path)

    monkeypatch.setitem(WRITERS, "ros1", bag_on_full_disk)
    now = [T0]
    events: list[BlackBoxEvent] = []
    rec = Recorder(snapshot_settings(tmp_path / "log.db"), robot_id="r1",
                   clock=lambda: now[0], schema_lookup={"/chatter": STRING}.get,
                   on_self_event=events.append)
    faulty_run(rec, now, faults=1)
    import time
    deadline = time.monotonic() + 20
    while rec.snapshots_written < 1:
        assert time.monotonic() < deadline, "the snapshot was not retried"
        time.sleep(0.05)
    rec.close()
    snapshots = tmp_path / "log.db.snapshots"
    (bag,) = snapshots.iterdir()  # no .part, no empty file left by the failed attempts
    assert bag.suffix == ".bag" and bag.stat().st_size > 1000
    with Store.open(tmp_path / "log.db", readonly=True) as store:
        (row,) = store.query(kinds=["snapshot"])
    assert row.payload["file"] == bag.name and row.payload["attempts"] == 3
    assert "error" not in row.payload and row.payload["messages"] > 0


# ---- under load ----------------------------------------------------------------------------


def changes(t: float, n: int, bad: bool) -> list[Observation]:
    code = Code.NO_STATE_FITS if bad else Code.GENERAL_OK
    return [Observation(t, "hz", Resource(topic=f"/t{k}"), code) for k in range(n)]


def test_on_a_simulated_clock_the_pipeline_waits_for_the_disk_and_drops_nothing(
        tmp_path: Path) -> None:
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=30.0, commit_rows=100,
                                    queue_limit=100, overflow="block", snapshot=None),
                   robot_id="r1")
    most = 0
    for i in range(40):  # 1,600 changes, far more than the queue holds
        rec.on_observations(T0 + i, changes(T0 + i, 40, i % 2 == 0))
        most = max(most, int(rec.health().values["queued_rows"]))
    rec.close()
    assert rec.dropped == 0 and most <= 100
    with Store.open(tmp_path / "log.db", readonly=True) as store:
        assert store.count("observation") + store.count("exceedance") == 1600


def test_in_real_time_the_least_valuable_rows_go_and_the_log_counts_them(
        tmp_path: Path) -> None:
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=30.0, commit_rows=10**6,
                                    queue_limit=100, snapshot=None), robot_id="r1")
    for i in range(40):
        rec.on_observations(T0 + i, changes(T0 + i, 40, i % 2 == 0))
        rec.on_diagnosis(Diagnosis(T0 + i, (frozenset({f"/n{i}"}),) if i % 2 == 0 else ()))
    rec.close()
    with Store.open(tmp_path / "log.db", readonly=True) as store:
        *_, counted = [e.payload for e in store.query(kinds=["blackbox_event"])
                       if e.payload.get("event") == "records_dropped"]  # totals so far
        assert store.count("failure") == 40  # never dropped: failures and own events
        kept_changes = store.count("observation") + store.count("exceedance")
    assert counted["total"] == rec.dropped > 0
    assert kept_changes + counted["by_kind"]["observation"] + \
        counted["by_kind"].get("exceedance", 0) == 1600


def test_a_slow_snapshot_never_holds_up_the_rows(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A capture that takes seconds to encode (a big bag) is written beside the log's
    commits, not before them."""
    import threading
    import time

    real = WRITERS["ros1"]
    writing = threading.Event()
    release = threading.Event()

    def slow_bag(messages, schemas, path):  # type: ignore[no-untyped-def]
        writing.set()
        release.wait(20)
        return real(messages, schemas, path)

    monkeypatch.setitem(WRITERS, "ros1", slow_bag)
    now = [T0]
    rec = Recorder(snapshot_settings(tmp_path / "log.db"), robot_id="r1",
                   clock=lambda: now[0], schema_lookup={"/chatter": STRING}.get)
    try:
        faulty_run(rec, now, faults=1)
        assert writing.wait(20), "the snapshot was never started"
        before = rec.written
        for i in range(5):  # rows that arrive while the snapshot is being written
            t = T0 + 1000 + i
            rec.on_observations(t, changes(t, 10, i % 2 == 0))
        deadline = time.monotonic() + 10
        while rec.written < before + 50:
            assert time.monotonic() < deadline, "rows waited for the snapshot"
            time.sleep(0.02)
        assert rec.snapshots_written == 0  # still being written
    finally:
        release.set()
        rec.close()
    assert rec.snapshots_written >= 1


# ---- closing -------------------------------------------------------------------------------


def test_no_recorder_event_reaches_a_closed_events_file(tmp_path: Path) -> None:
    """Closing the recorder writes its last snapshot (failing here: the directory is a
    file); that must land in the log, not in the already closed ``--events`` sink."""
    (tmp_path / "log.db.snapshots").write_text("in the way")
    source = MemorySource([], start_time=T0)
    events_file = tmp_path / "events.jsonl"
    sink = JsonLinesSink(events_file, observations=False, diagnoses=False)
    now = [T0]
    rec = Recorder(snapshot_settings(tmp_path / "log.db"), robot_id="r1",
                   clock=lambda: now[0], schema_lookup={"/chatter": STRING}.get)
    pipeline = Pipeline(source, [], [sink, rec])
    rec.on_self_event = pipeline.emit_event
    pipeline.start()
    payload = struct.pack("<I", 3) + b"abc"
    rec.on_message(MessageArrival(T0, "/chatter", "/talker", 7, raw=lambda: payload))
    rec.on_diagnosis(Diagnosis(T0, (frozenset({"/usb_cam"}),), (), "camera"))
    pipeline.close()  # the capture is still open: close() flushes it
    assert pipeline.stats.errors == 0
    assert [r["kind"] for r in read_records(events_file)][-1] == "stop"
    with Store.open(tmp_path / "log.db", readonly=True) as store:
        (row,) = store.query(kinds=["snapshot"])
    assert "error" in row.payload


# ---- the record path -----------------------------------------------------------------------


def test_record_refuses_a_file_that_is_not_a_health_log(tmp_path: Path) -> None:
    config = tmp_path / "my_config.yaml"
    text = "robot:\n  id: precious\n"
    config.write_text(text)
    result = blackbox("run", "--simulated-clock", "--duration", "2", "--quiet",
                      "--record", str(config))
    assert result.returncode == 2
    assert "is not a health log" in result.stderr and "--force" in result.stderr
    assert "Traceback" not in result.stderr
    assert config.read_text() == text and sorted(tmp_path.iterdir()) == [config]

    forced = blackbox("run", "--simulated-clock", "--duration", "2", "--quiet",
                      "--record", str(config), "--force")
    assert forced.returncode == 0, forced.stderr
    (aside,) = tmp_path.glob("my_config.yaml.replaced-*")
    assert aside.read_text() == text  # moved aside, never overwritten
    with Store.open(config, readonly=True) as store:
        (start,) = [e for e in store.query(kinds=["blackbox_event"],
                                           entity="blackbox/recorder")
                    if e.payload.get("event") == "start"]
    assert start.payload["moved_aside"] == str(aside)


def test_a_foreign_database_is_refused_by_the_recorder_too(tmp_path: Path) -> None:
    import sqlite3

    other = tmp_path / "inventory.db"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE parts (name TEXT)")
    db.commit()
    db.close()
    before = other.read_bytes()
    with pytest.raises(RecordPathError, match="not a health log"):
        Recorder(RecorderSettings(other, snapshot=None), robot_id="r1")
    assert other.read_bytes() == before


@pytest.mark.parametrize(("args", "message"), [
    (["--record", "{tmp}"], "is a directory"),
    (["--record", "/proc/blackbox.db"], "proc pseudo file system"),
    (["--record", "/dev/null/x.db"], "/dev/null is not a directory"),
    (["--record", "{tmp}/missing/x.db"], "does not exist"),
    (["--dds", "--domain", "999"], "must be 0..232"),
    (["--duration", "-5"], "must be a positive number of seconds"),
])
def test_unusable_paths_and_arguments_exit_2_with_a_message(tmp_path: Path, args: list[str],
                                                            message: str) -> None:
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    duration = [] if "--duration" in args else ["--duration", "1"]
    result = blackbox("run", "--simulated-clock", "--quiet", *duration, *args)
    assert result.returncode == 2, result.stderr
    assert message in result.stderr
    assert "Traceback" not in result.stderr


def test_recorder_path_under_a_missing_directory_in_the_configuration(tmp_path: Path) -> None:
    config = tmp_path / "bb.yaml"
    thesis = Path(__file__).resolve().parent.parent / "src/blackbox/configs/thesis.yaml"
    config.write_text(thesis.read_text() + "\nrecorder:\n  path: nowhere/log.db\n")
    result = blackbox("run", "--config", str(config), "--simulated-clock", "--quiet",
                      "--duration", "1")
    assert result.returncode == 2
    assert "nowhere does not exist" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "nowhere").exists()
