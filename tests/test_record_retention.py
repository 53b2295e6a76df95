"""Retention: the log stays in its budget; samples go first, failures last; capacity."""

from __future__ import annotations

from pathlib import Path

from blackbox.cli import main
from blackbox.record.retention import (
    Retention,
    enforce_directory,
    estimate_capacity,
    thesis_robot,
)
from blackbox.record.store import Row, Store

CHANNELS = [(f"/topic_{k}", "hz", f'{{"topic":"/topic_{k}"}}') for k in range(10)]


def filled(path: Path, hours: int = 4) -> Store:
    """10 channels sampled every 10 s for ``hours``, a failure and a change every hour."""
    store = Store.open(path, durability="normal")
    rows = []
    for s in range(0, hours * 3600, 10):
        for ch in CHANNELS:
            rows.append(Row(float(s), "sample", ch, 0,
                            {"values": {"period": 0.0667 + s * 1e-9}, "states": [1]}))
        if s % 3600 == 0:
            rows.append(Row(float(s), "failure", None, None, {"components": ["/usb_cam"]}))
            rows.append(Row(float(s), "exceedance", CHANNELS[0], -2, {"values": {}}))
    store.append(rows)
    store.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return store


def test_over_budget_thins_old_samples_first_and_keeps_everything_else(tmp_path: Path) -> None:
    store = filled(tmp_path / "log.db")
    used = store.used_bytes()
    samples = store.count("sample")
    retention = Retention(budget_bytes=int(used * 0.8))
    report = retention.enforce(store)
    assert report.thinned > 0 and report.dropped == 0
    assert report.after_bytes <= retention.budget_bytes * retention.low
    assert store.count("failure") == 4 and store.count("exceedance") == 4
    left = store.count("sample")
    assert left < samples
    # The newest hour is untouched: one sample per channel every 10 s.
    newest = list(store.query(start=3 * 3600.0, kinds=["sample"]))
    assert len(newest) == 360 * 10
    # The oldest hour kept one in four samples of each channel: one every 40 s.
    oldest = [e.time for e in store.query(entity="/topic_3", end=3599.0, kinds=["sample"])]
    assert oldest[:3] == [0.0, 40.0, 80.0]
    assert all(e.payload.get("thinned") == 4 for e in store.query(end=100.0, kinds=["sample"]))
    assert store.integrity_check() == "ok"
    store.close()


def test_far_over_budget_drops_samples_before_failures(tmp_path: Path) -> None:
    with Store.open(tmp_path / "reference.db") as ref:  # the log without its samples
        ref.append([Row(0.0, "failure", None, None, {"components": ["/usb_cam"]})] * 2 +
                   [Row(0.0, "exceedance", CHANNELS[0], -2, {"values": {}})] * 2)
        ref.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        without_samples = ref.used_bytes()
    store = filled(tmp_path / "log.db", hours=2)
    samples = store.count("sample")
    report = Retention(budget_bytes=2 * without_samples).enforce(store)
    assert report.dropped > 0
    assert store.count("sample") < samples // 20
    assert store.count("failure") == 2 and store.count("exceedance") == 2
    store.close()


def test_under_budget_nothing_happens(tmp_path: Path) -> None:
    store = filled(tmp_path / "log.db", hours=1)
    n = store.count()
    report = Retention(budget_bytes=10**9).enforce(store)
    assert not report.acted and store.count() == n
    store.close()


def test_snapshot_directory_loses_the_oldest_of_its_own_files_only(tmp_path: Path) -> None:
    import os

    for i in range(5):
        f = tmp_path / f"snap{i}.bag"
        f.write_bytes(b"b" * 1000)
        os.utime(f, (1000 + i, 1000 + i))
    user = tmp_path / "notes.bag"  # same suffix, older, bigger than the budget: not ours
    user.write_bytes(b"u" * 5000)
    os.utime(user, (10, 10))
    outside = ["../escape.bag", "/etc/passwd", ".hidden.bag", "snap-a.txt"]
    removed = enforce_directory(tmp_path, 2500, [f"snap{i}.bag" for i in range(5)] + outside)
    assert removed == ["snap0.bag", "snap1.bag", "snap2.bag"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.bag", "snap3.bag", "snap4.bag"]


def test_capacity_of_the_thesis_robot_meets_4000_hours_in_1_gb() -> None:
    est = estimate_capacity(thesis_robot(), 10**9)
    # 10 observers at the default 60 s interval: 600 samples an hour, plus one fault's
    # 30 s of 1 s samples, its two state changes, a diagnosis pair and a failure pair.
    assert est.entries_per_hour == 600 + 33
    assert est.hours > 4000


def test_capacity_command_prints_hours(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["log", "capacity", "--observers", "4", "--every", "1", "--budget", "1 GB"]) == 0
    out = capsys.readouterr().out
    assert "4 observers every 1 s: 4 observers" in out
    assert "operating hours" in out and "4,000 h target" in out
