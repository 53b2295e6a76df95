"""A damaged health log is salvaged, not refused whole: ``log query/export --salvage`` read
every intact entry and say what was lost; ``log check`` says whether the log is intact.

The logs are real: written by the recorder (rows of ``entries`` and LZ4/MessagePack frames,
some large enough to spill onto overflow pages), then cut short or holed the way a disk
loses data, and read back through the command line.
"""

from __future__ import annotations

import json
import re
import shutil
import sqlite3
import time
from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.health.identity import EventLedger
from blackbox.model import Code, Observation, Resource
from blackbox.record import Recorder, Store
from blackbox.record.salvage import salvage
from blackbox.record.settings import RecorderSettings
from blackbox.record.store import LogEntry

T0 = 1_700_000_000.0


def write_log(path: Path) -> dict[int, LogEntry]:
    """A log of about 9,000 entries: changes of 30 topics committed a few at a time (rows),
    then bursts committed together (frames, the last ones of several pages each)."""
    # A ledger of its own (as beside a health publisher that published nothing): the rows
    # carry no event identities, so the page layout the cuts below rely on is the same.
    rec = Recorder(RecorderSettings(path, commit_interval=0.05, snapshot=None,
                                    queue_limit=1_000_000), robot_id="salvage-bot",
                   clock=lambda: T0, ledger=EventLedger())
    resources = [Resource(topic=f"/t{k}") for k in range(30)]
    t = T0
    for step in range(300):
        batch = []
        for k, r in enumerate(resources):
            t += 0.001
            code = Code.GENERAL_OK if (step + k) % 2 else Code.NO_STATE_FITS
            batch.append(Observation(t, "hz", r, code, values={"step": step, "k": k},
                                     message="m" * (k * 3)))
        rec.on_observations(t, batch)
        if step % 10 == 0:
            time.sleep(0.06)  # a commit: the next rows are few per channel
    time.sleep(0.1)
    for _ in range(3):  # bursts: hundreds per channel in one commit, stored as frames
        batch = []
        for i in range(400):
            for k, r in enumerate(resources[:3]):
                t += 0.0001
                code = Code.GENERAL_OK if i % 2 else Code.NO_STATE_FITS
                batch.append(Observation(t, "hz", r, code, values={"burst": i, "x": i * 0.5},
                                         message=f"burst {i} on {k}"))
        rec.on_observations(t, batch)
        time.sleep(0.15)
    rec.close()
    with Store.open(path, readonly=True) as store:
        entries = {e.id: e for e in store.query()}
        assert store.execute("SELECT count(*) FROM frames WHERE length(data) > 4000"
                             ).fetchone()[0] > 0, "some frames overflow their page"
    assert len(entries) > 9000
    return entries


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[int, LogEntry]]:
    path = tmp_path_factory.mktemp("salvage") / "log.db"
    return path, write_log(path)


def damaged_copy(original: Path, target: Path, cut: int = 0,
                 zero_pages: tuple[int, ...] = ()) -> Path:
    shutil.copyfile(original, target)
    with target.open("r+b") as fh:
        for page in zero_pages:
            fh.seek((page - 1) * 4096)
            fh.write(b"\0" * 4096)
        if cut:
            fh.truncate(target.stat().st_size - cut)
    return target


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def lost_ids(err: str) -> list[tuple[int, float]]:
    """The lost id ranges the report names (``end`` as infinity)."""
    rows = [(int(a), float("inf") if b == "end" else int(b))
            for a, b in re.findall(r"lost: entry ids (\d+)\.\.(\d+|end)", err)]
    return rows + [(int(a), float("inf")) for a in re.findall(r"have ids from (\d+) on", err)]


def test_a_log_cut_short_by_a_few_kb_is_salvaged_and_the_loss_is_named(
        original: tuple[Path, dict[int, LogEntry]], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    source, entries = original
    log = damaged_copy(source, tmp_path / "cut.db", cut=12 * 1024)

    code, _, err = run(capsys, "log", "query", "--db", str(log))
    assert code == 1 and "--salvage" in err and "malformed" in err

    code, out, err = run(capsys, "log", "query", "--db", str(log), "--salvage",
                         "--format", "jsonl")
    assert code == 0, err
    got = {e["id"]: e for e in map(json.loads, out.splitlines())}
    assert len(got) >= 0.95 * len(entries), f"salvaged {len(got)} of {len(entries)}"
    for eid, entry in got.items():  # everything salvaged is exactly what was written
        assert entry == json.loads(json.dumps(entries[eid].to_dict())), eid
    assert "pages missing" in err
    ranges = lost_ids(err) + [(f.first_id, f.last_id) for f in salvage(log).report.lost_frames]
    missing = set(entries) - set(got)
    assert missing, "a cut of 12 KB loses something"
    assert all(any(a <= i <= b for a, b in ranges) for i in missing), \
        "every entry not salvaged lies in a range the report names"
    assert f"salvaged {len(got)} entries" in err

    out_file = tmp_path / "cut.jsonl"
    code, _, err = run(capsys, "log", "export", "--db", str(log), "--salvage", "-o",
                       str(out_file))
    assert code == 0, err
    assert [json.loads(line)["id"] for line in out_file.read_text().splitlines()] == \
        [json.loads(line)["id"] for line in out.splitlines()]


def test_frames_whose_pages_are_lost_are_reported_with_their_ids_and_times(
        original: tuple[Path, dict[int, LogEntry]], tmp_path: Path) -> None:
    source, entries = original
    with Store.open(source, readonly=True) as store:
        frames = store.execute("SELECT count(*), sum(count) FROM frames").fetchone()
    # Cut into the last frames' overflow pages: their rows survive, their data does not.
    for cut_pages in range(1, 40):
        found = salvage(damaged_copy(source, tmp_path / f"cut{cut_pages}.db",
                                     cut=cut_pages * 4096))
        if found.report.lost_frames:
            break
    else:
        pytest.fail("no cut of up to 40 pages lost a frame's data")
    lost = found.report.lost_frames[0]
    assert lost.first_id is not None and lost.count and lost.t_min is not None
    framed = [e for e in entries.values() if lost.first_id <= e.id <= lost.last_id
              and e.time >= lost.t_min and e.time <= lost.t_max]
    assert len(framed) >= lost.count  # the ids and times name the entries that went
    lines = found.report.lines(found.entries)
    assert any(f"lost: frame {lost.frame} data ({lost.count} entries" in line for line in lines)
    assert found.report.frames < frames[0]


def entry_leaf_pages(log: Path) -> list[int]:
    """Pages holding rows of ``entries`` (SQLite's ``dbstat`` table), in file order."""
    db = sqlite3.connect(f"{log.resolve().as_uri()}?mode=ro", uri=True)
    try:
        return [r[0] for r in db.execute("SELECT pageno FROM dbstat WHERE name = 'entries' "
                                         "AND pagetype = 'leaf' ORDER BY pageno")]
    finally:
        db.close()


def test_a_hole_in_the_middle_loses_only_its_page(
        original: tuple[Path, dict[int, LogEntry]], tmp_path: Path) -> None:
    source, entries = original
    leaves = entry_leaf_pages(source)
    log = damaged_copy(source, tmp_path / "hole.db", zero_pages=(leaves[20], leaves[200]))
    found = salvage(log)
    got = {e.id: e for e in found.entries}
    missing = set(entries) - set(got)
    lines = found.report.lines(found.entries)
    ranges = lost_ids("\n".join(lines))
    assert len(ranges) == 2 and all(b - a < 100 for a, b in ranges), lines
    assert missing == {i for a, b in ranges for i in range(a, b + 1)} & set(entries)
    assert all(got[i] == entries[i] for i in got)
    assert any("between time" in line for line in lines)


def test_an_intact_log_salvages_to_exactly_what_a_query_reads(
        original: tuple[Path, dict[int, LogEntry]]) -> None:
    source, entries = original
    found = salvage(source)
    assert {e.id: e for e in found.entries} == entries
    assert found.robot_id == "salvage-bot"
    assert not found.report.damaged
    assert found.report.lines(found.entries)[-1] == "nothing lost"


def test_log_check_says_intact_or_damaged(original: tuple[Path, dict[int, LogEntry]],
                                          tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    source, entries = original
    code, out, _ = run(capsys, "log", "check", "--db", str(source))
    assert code == 0, out
    assert "integrity_check: ok" in out and out.rstrip().endswith("intact")
    assert f"entries: {len(entries)} (" in out and re.search(r"frames: \d+ decodable, 0 not", out)
    assert f"time range: {min(e.time for e in entries.values())!r}.." in out

    cut = damaged_copy(source, tmp_path / "cut.db", cut=8192)
    code, out, _ = run(capsys, "log", "check", "--db", str(cut))
    assert code == 1
    assert "salvage: salvaged" in out and "pages missing" in out and "damaged" in out

    holed = damaged_copy(source, tmp_path / "holed.db",
                         zero_pages=(entry_leaf_pages(source)[100],))
    code, out, _ = run(capsys, "log", "check", "--db", str(holed))
    assert code == 1 and "lost: entry ids" in out

    foreign = tmp_path / "notes.txt"
    foreign.write_text("not a log\n" * 50)
    code, _, err = run(capsys, "log", "check", "--db", str(foreign))
    assert code == 2 and "not a health log" in err and "Traceback" not in err
    assert foreign.read_text() == "not a log\n" * 50


def test_salvage_reads_the_wal_of_a_crashed_log(tmp_path: Path) -> None:
    """A log killed before its first checkpoint: most of it is in the WAL."""
    live = tmp_path / "live.db"
    rec = Recorder(RecorderSettings(live, commit_interval=0.02, snapshot=None), robot_id="w")
    for i in range(50):
        rec.on_observations(T0 + i, [Observation(T0 + i, "hz", Resource(topic="/a"),
                                                 Code.GENERAL_OK if i % 2 else
                                                 Code.NO_STATE_FITS)])
    deadline = time.monotonic() + 10
    while rec.written < 51:
        assert time.monotonic() < deadline, "the recorder did not commit 51 rows"
        time.sleep(0.02)
    crashed = tmp_path / "crashed"
    crashed.mkdir()
    shutil.copyfile(live, crashed / "log.db")
    shutil.copyfile(f"{live}-wal", crashed / "log.db-wal")
    rec.close()
    wal_before = (crashed / "log.db-wal").read_bytes()
    found = salvage(crashed / "log.db")
    assert [e.time for e in found.entries if e.kind in ("observation", "exceedance")] == \
        [T0 + i for i in range(50)]
    assert found.report.wal_applied is True
    assert (crashed / "log.db-wal").read_bytes() == wal_before, "the original is only read"


def test_rows_under_a_lost_interior_page_are_found_on_their_orphaned_pages(
        original: tuple[Path, dict[int, LogEntry]], tmp_path: Path) -> None:
    """The root pages of ``entries`` and ``frames`` zeroed: no walk reaches a leaf, yet
    every leaf is intact and is read; the report says the rows were found that way."""
    source, entries = original
    db = sqlite3.connect(f"{source.resolve().as_uri()}?mode=ro", uri=True)
    roots = tuple(r[0] for r in db.execute(
        "SELECT rootpage FROM sqlite_master WHERE name IN ('entries', 'frames')"))
    db.close()
    found = salvage(damaged_copy(source, tmp_path / "rootless.db", zero_pages=roots))
    assert {e.id: e for e in found.entries} == entries
    lines = found.report.lines(found.entries)
    assert any(line.startswith("entries: ") and "found on pages whose parent page was lost"
               in line for line in lines), lines
