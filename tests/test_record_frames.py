"""Logged observations stored in frames read back exactly as rows of ``entries`` would.

The reference for every comparison is the same rows written with their payload already a
dictionary (``observation_payload``), which the store keeps one row per entry: ids, times,
kinds, channels, codes and payloads must be equal, whatever the query.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.identity import EventId
from blackbox.model import Code, Observation, Resource, State
from blackbox.record import Store
from blackbox.record.policy import LoggingPolicy, PolicyTracker, observation_payload
from blackbox.record.store import FRAME_MIN, KINDS, THINNED, Row, RowTuple
from conftest import wait_until
from crash_support import sigkill_after

T0 = 1.7e9
OK, SLOW = (State(1, "ok"),), (State(2, "too_slow"),)


def logged_rows(steps: int = 40, topics: int = 12) -> list[RowTuple]:
    """What the recorder hands its store: the policy's decisions on a stream where every
    topic turns faulty and healthy again, with samples in between, plus robot-wide rows."""
    tracker = PolicyTracker(LoggingPolicy())
    resources = [Resource(topic=f"/robot/t{k:02d}") for k in range(topics)]
    rows: list[RowTuple] = []
    for step in range(steps):
        t = T0 + step * 0.5
        for k, r in enumerate(resources):
            faulty = (step + k) % 10 < 3
            values: dict[str, Any] = {"period": 0.066 + k * 1e-4, "seq": step * topics + k}
            if step == 9 and k == 1:  # a change: logged
                values["period"] = math.nan  # JSON has no NaN: read back as text, as before
            obs = Observation(t + k * 1e-3, "hz", r, Code.NO_STATE_FITS if faulty
                              else Code.GENERAL_OK, SLOW if faulty else OK, values,
                              "too slow" if faulty else "")
            d = tracker.decide(obs)
            if d is not None:
                rows.append((obs.time, d.kind, d.channel, obs.code, obs))
        if step % 9 == 0:
            rows.append(Row(t, "diagnosis", None, None, {"candidates": [["/robot/t01"]]}))
    return rows


def as_dicts(rows: list[RowTuple]) -> list[RowTuple]:
    return [(t, kind, ch, int(code) if code is not None else None,
             observation_payload(p, kind != "sample") if isinstance(p, Observation) else p)
            for t, kind, ch, code, p in rows]


def pair(tmp_path: Path, rows: list[RowTuple], commit: int = 10_000) -> tuple[Store, Store]:
    framed, plain = Store.open(tmp_path / "framed.db"), Store.open(tmp_path / "plain.db")
    for start in range(0, len(rows), commit):
        framed.append(rows[start:start + commit])
        plain.append(as_dicts(rows[start:start + commit]))
    return framed, plain


def same(a: Any, b: Any) -> bool:
    """Equality where NaN equals NaN (and the text 'nan' stays text)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_observations_go_into_frames_and_read_back_equal(tmp_path: Path) -> None:
    rows = logged_rows()
    framed, plain = pair(tmp_path, rows, commit=len(rows))
    frames = framed.execute("SELECT count(*), sum(count) FROM frames").fetchone()
    assert frames[0] > 0 and frames[1] > len(rows) // 2  # most went into frames
    assert plain.execute("SELECT count(*) FROM frames").fetchone()[0] == 0
    got, want = list(framed.query()), list(plain.query())
    assert len(got) == len(rows)
    assert same([e.to_dict() for e in got], [e.to_dict() for e in want])
    nan = [e for e in got if e.payload.get("values", {}).get("period") == "nan"]
    assert len(nan) == 1  # the NaN, as text like every row of entries
    assert framed.count() == plain.count() == len(rows)
    for kind in ("sample", "observation", "exceedance", "diagnosis"):
        assert framed.count(kind) == plain.count(kind) > 0
        assert same(framed.latest(kind).to_dict(), plain.latest(kind).to_dict())  # type: ignore[union-attr]
    for e in want[::7]:
        assert same(framed.get(e.id).to_dict(), e.to_dict())  # type: ignore[union-attr]
    assert framed.get(10**9) is None


@pytest.mark.parametrize("filters", [
    {}, {"entity": "/robot/t03"}, {"entity": "/robot/t0*"}, {"characteristic": "hz"},
    {"start": T0 + 3.0, "end": T0 + 9.0}, {"start": T0 + 4.0005},
    {"kinds": ["exceedance", "diagnosis"]}, {"kinds": ["sample"], "entity": "/robot/t1?"},
    {"limit": 17}, {"start": T0 + 2.0, "limit": 5}, {"after_id": 120},
    {"after_id": 40, "kinds": ["observation"], "limit": 9},
])
def test_every_query_answers_as_if_all_were_rows(tmp_path: Path, filters: dict[str, Any]) -> None:
    rows = logged_rows()
    framed, plain = pair(tmp_path, rows, commit=97)  # frames of several commits interleave
    got = [e.to_dict() for e in framed.query(**filters)]
    want = [e.to_dict() for e in plain.query(**filters)]
    assert got and same(got, want)


def test_small_groups_and_unencodable_values_are_rows_of_entries(tmp_path: Path) -> None:
    r = Resource(topic="/odd")
    few = [Observation(T0 + i, "hz", Resource(topic=f"/few{i}"), Code.GENERAL_OK, OK,
                       {"period": 1.0}) for i in range(3)]
    odd = [Observation(T0 + i, "hz", r, Code.GENERAL_OK, OK, {"period": object()})
           for i in range(FRAME_MIN * 2)]
    rows: list[RowTuple] = [(o.time, "observation", ("/few", "hz", str(i)), o.code, o)
                            for i, o in enumerate(few)]
    rows += [(o.time, "observation", ("/odd", "hz", "{}"), o.code, o) for o in odd]
    with Store.open(tmp_path / "log.db") as store:
        ids = store.append(rows)
        assert store.execute("SELECT count(*) FROM frames").fetchone()[0] == 0
        got = sorted(store.query(), key=lambda e: e.id)
        assert [e.id for e in got] == ids == list(range(ids[0], ids[0] + len(rows)))
        assert got[0].payload["values"] == {"period": 1.0}
        assert str(got[-1].payload["values"]["period"]).startswith("<object object")


def test_ids_follow_the_rows_order_across_both_tables(tmp_path: Path) -> None:
    r = Resource(topic="/a")
    obs = [Observation(T0, "hz", r, Code.GENERAL_OK, OK, {"seq": i}) for i in range(20)]
    rows: list[RowTuple] = [(T0, "sample", ("/a", "hz", "{}"), 0, o) for o in obs[:10]]
    rows.append(Row(T0, "blackbox_event", None, None, {"event": "stop"}))
    rows += [(T0, "sample", ("/a", "hz", "{}"), 0, o) for o in obs[10:]]
    with Store.open(tmp_path / "log.db") as store:
        store.append([Row(T0, "blackbox_event", None, None, {"event": "start"})])
        ids = store.append(rows)
        got = list(store.query())  # all at one time: id order is hand-over order
        assert [e.id for e in got[1:]] == ids
        assert [e.payload.get("event", e.payload.get("values", {}).get("seq"))
                for e in got] == ["start", *range(10), "stop", *range(10, 20)]
        assert store.append([Row(T0 + 1, "config", None, None, {"version": None, "text": ""})]) \
            == [ids[-1] + 1]


def test_retention_thins_and_drops_framed_samples_like_rows(tmp_path: Path) -> None:
    rs = [Resource(topic=f"/s{k}") for k in range(4)]
    with Store.open(tmp_path / "log.db") as store:
        for commit in range(10):  # 10 commits x 4 channels x 20 samples, all framed
            store.append([(T0 + commit * 20 + i, "sample", (f"/s{k}", "hz", "{}"), 0,
                           Observation(T0 + commit * 20 + i, "hz", r, Code.GENERAL_OK, OK,
                                       {"i": commit * 20 + i}))
                          for i in range(20) for k, r in enumerate(rs)])
        store.append([Row(T0, "failure", None, None, {"components": ["/s1"]})])
        assert store.execute("SELECT count(*) FROM frames").fetchone()[0] == 40
        removed = store.thin_samples(KINDS["sample"])
        assert removed == 4 * 100 * 3 // 4  # the older half, three in four per channel
        for k in range(4):
            kept = list(store.query(entity=f"/s{k}"))
            old = [e for e in kept if e.time < T0 + 100]
            assert [e.payload["values"]["i"] for e in old] == list(range(0, 100, THINNED))
            assert all(e.payload["thinned"] == THINNED for e in old)
            assert [e.payload["values"]["i"] for e in kept if e.time >= T0 + 100] == \
                list(range(100, 200))
            assert all("thinned" not in e.payload for e in kept if e.time >= T0 + 100)
        before = store.count("sample")
        dropped = store.drop_least_valuable(((KINDS["sample"],),))
        assert 0 < dropped <= before // 10 + 20 and store.count("sample") == before - dropped
        oldest = min(e.time for e in store.query(kinds=["sample"]))
        assert all(e.time >= oldest for e in store.query(kinds=["sample"]))
        assert store.count("failure") == 1
        assert store.integrity_check() == "ok"


WRITER = """
import sys, time
from blackbox.model import Code, Observation, Resource, State
from blackbox.record import Recorder
from blackbox.record.settings import RecorderSettings
rec = Recorder(RecorderSettings(sys.argv[1], commit_interval=0.1, snapshot=None),
               robot_id="frames")
resources = [Resource(topic=f"/t{k}") for k in range(10)]
states = ((State(1, "ok"),), (State(2, "too_slow"),))
handed = open(sys.argv[2], "w")
print("ready", flush=True)
seq = 0
while True:  # every observation a change: 10 channels x 100 a batch, framed at every commit
    batch = []
    for _ in range(1000):
        bad = (seq // 10) % 2
        batch.append(Observation(time.time(), "hz", resources[seq % 10],
                                 Code.NO_STATE_FITS if bad else Code.GENERAL_OK, states[bad],
                                 {"seq": seq, "half": seq / 2}, "m" if bad else ""))
        seq += 1
    rec.on_observations(time.time(), batch)
    handed.write(f"{time.time()} {seq - 1}\\n")
    handed.flush()
    time.sleep(0.005)
"""


def committed_frames(log: Path) -> int:
    """Frames committed to ``log`` so far, read without disturbing the writer."""
    if not log.exists():
        return 0
    try:
        db = sqlite3.connect(f"{log.as_uri()}?mode=ro", uri=True, timeout=1.0)
        try:
            return int(db.execute("SELECT count(*) FROM frames").fetchone()[0])
        finally:
            db.close()
    except sqlite3.Error:
        return 0  # not created yet, or its schema not committed yet


@pytest.mark.slow
def test_sigkill_of_a_writer_mid_batch_keeps_every_acknowledged_observation(
        tmp_path: Path) -> None:
    """Killed while frames are being written: everything handed over before the committed
    progress marker is in the log, as a prefix without holes, and reads back as written."""
    src = str(Path(__file__).resolve().parent.parent / "src")
    env = {**os.environ, "PYTHONPATH": src + os.pathsep + os.environ.get("PYTHONPATH", "")}
    for run in range(5):
        log, handed = tmp_path / f"run{run}.db", tmp_path / f"run{run}.txt"
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(log), str(handed)],
                                stdout=subprocess.PIPE, env=env)

        def ready(proc: subprocess.Popen[bytes] = proc, log: Path = log) -> None:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == b"ready"
            # the first commit of frames, then the kill's delay (a fixed 0.3 s here once
            # saw no commit at all on a loaded machine)
            wait_until(lambda: committed_frames(log) > 0, "a first commit of frames",
                       timeout=30)

        sigkill_after(proc, ready, 0.1 + 0.17 * run)
        acknowledged = [(float(w), int(s)) for w, s in
                        (line.split() for line in handed.read_text().splitlines()
                         if len(line.split()) == 2)]
        with Store.open(log) as store:  # replays the WAL, as the next start would
            assert store.integrity_check() == "ok"
            marker = json.loads(store.meta("progress") or "{}")
            assert store.execute("SELECT count(*) FROM frames").fetchone()[0] > 0
            got = list(store.query(kinds=["observation", "exceedance"]))
        seqs = sorted(e.payload["values"]["seq"] for e in got)
        assert seqs == list(range(len(seqs))), "a committed prefix, without holes"
        promised = max((s for w, s in acknowledged if w < marker["wall"]), default=-1)
        assert promised >= 0 and len(seqs) - 1 >= promised, (
            f"run {run}: the marker promises seq {promised}, the log ends at {len(seqs) - 1}")
        for e in got:
            seq = e.payload["values"]["seq"]
            bad = (seq // 10) % 2
            assert e.entity == f"/t{seq % 10}" and e.characteristic == "hz"
            assert e.kind == ("exceedance" if bad else "observation")
            if bad:  # each fault's onset is an event of its own, with its identity
                assert EventId.parse(e.payload.pop("event_id")) is not None
            assert e.payload == {"values": {"seq": seq, "half": seq / 2},
                                 "states": [2 if bad else 1],
                                 "state_names": ["too_slow" if bad else "ok"],
                                 "code_name": "NO_STATE_FITS" if bad else "GENERAL_OK",
                                 **({"message": "m"} if bad else {})}
