"""``blackbox run`` and ``blackbox demo`` as a user runs them: real processes, real files."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from blackbox.output.jsonlines import read_records

BLACKBOX = [sys.executable, "-m", "blackbox"]


def blackbox(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*BLACKBOX, *args], capture_output=True, text=True, timeout=timeout)


def test_simulated_run_writes_observations_as_documented_json_lines(tmp_path: Path) -> None:
    out = tmp_path / "obs.jsonl"
    events = tmp_path / "events.jsonl"
    result = blackbox("run", "--source", "sim:thesis", "--duration", "20", "--simulated-clock",
                      "--quiet", "--observations", str(out), "--events", str(events))
    assert result.returncode == 0, result.stderr
    records = read_records(out)
    assert len(records) == 200  # ten observers, once per simulated second
    first = records[0]
    assert first["record"] == "observation" and first["schema"] == 1
    assert set(first) >= {"time", "observer", "resource", "code", "code_name", "faulty",
                          "states", "values", "message"}
    assert set(first["resource"]) == {"node", "topic", "publishers", "topic_b", "interface"}
    assert not any(r["faulty"] for r in records)
    assert [r["kind"] for r in read_records(events)] == ["start", "stop"]
    assert "20.0 s observed" in result.stderr


def test_injected_faults_appear_with_their_ground_truth(tmp_path: Path) -> None:
    faults = tmp_path / "faults.yaml"
    faults.write_text("faults:\n  - {kind: kill, component: /usb_cam, start: 10, end: 20}\n")
    out, truth = tmp_path / "obs.jsonl", tmp_path / "truth.jsonl"
    result = blackbox("run", "--duration", "30", "--simulated-clock", "--quiet",
                      "--faults", str(faults), "--ground-truth", str(truth),
                      "--observations", str(out))
    assert result.returncode == 0, result.stderr
    dead = [r for r in read_records(out) if r["observer"] == "activated" and r["faulty"]]
    assert {r["resource"]["node"] for r in dead} == {"/usb_cam"}
    assert min(r["time"] for r in dead) <= 11.0
    assert [(t["kind"], t["component"], t["start"], t["end"])
            for t in read_records(truth)] == [("kill", "/usb_cam", 10.0, 20.0)]


def test_ctrl_c_stops_a_real_time_run_cleanly(tmp_path: Path) -> None:
    out, events = tmp_path / "obs.jsonl", tmp_path / "events.jsonl"
    proc = subprocess.Popen([*BLACKBOX, "run", "--quiet", "--observations", str(out),
                             "--events", str(events)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and (not out.exists() or out.stat().st_size == 0):
            time.sleep(0.1)
        assert out.exists() and out.stat().st_size > 0, "no observation within 30 s"
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    for line in out.read_text().splitlines():
        json.loads(line)
    assert read_records(events)[-1]["kind"] == "stop"


def test_bad_configuration_and_unknown_source_exit_2_without_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("observers:\n  - type: hz\n    topic: /a\n    filter: {type: mean, "
                   "window_size: -3}\n")
    result = blackbox("run", "--config", str(bad), "--simulated-clock", "--duration", "1")
    assert result.returncode == 2
    assert f"{bad}:4:" in result.stderr and "window_size" in result.stderr
    assert "Traceback" not in result.stderr

    result = blackbox("run", "--source", "carrier-pigeon", "--duration", "1")
    assert result.returncode == 2
    assert "unknown source" in result.stderr and "Traceback" not in result.stderr


def test_fast_demo_runs_with_random_faults_and_records_them(tmp_path: Path) -> None:
    result = blackbox("demo", "--fast", "--duration", "120", "--out", str(tmp_path))
    assert result.returncode == 0, result.stderr
    truth = read_records(tmp_path / "ground_truth.jsonl")
    assert truth, "a random campaign over 120 s injects faults"
    faulty = [r for r in read_records(tmp_path / "observations.jsonl") if r["faulty"]]
    assert faulty
    assert "FAULT" in result.stdout


def test_run_keeps_a_health_log_with_failures_and_their_snapshots(tmp_path: Path) -> None:
    faults = tmp_path / "faults.yaml"
    faults.write_text("faults:\n  - {kind: kill, component: /usb_cam, start: 10, end: 20}\n")
    db = tmp_path / "bb.db"
    result = blackbox("run", "--duration", "30", "--simulated-clock", "--quiet",
                      "--faults", str(faults), "--record", str(db))
    assert result.returncode == 0, result.stderr
    query = blackbox("log", "query", "--db", str(db), "--kind", "failure", "--format", "jsonl")
    assert query.returncode == 0, query.stderr
    failures = [json.loads(line) for line in query.stdout.splitlines()]
    detected = [f for f in failures if f["payload"].get("category") == "detection"]
    assert detected and detected[0]["payload"]["components"] == ["/usb_cam"]
    snapshots = list((tmp_path / "bb.db.snapshots").glob("*.mcap"))
    assert snapshots, "a failure writes the flight-recorder snapshot"


def test_demo_runs_black_box_and_station_as_two_processes_over_dds(tmp_path: Path) -> None:
    from blackbox.station.auth import Auth
    from blackbox.station.store import StationStore

    result = blackbox("demo", "--duration", "8", "--out", str(tmp_path), "--bind",
                      "127.0.0.1:0", timeout=90)
    assert result.returncode == 0, result.stderr
    assert re.search(r"station: http://127\.0\.0\.1:\d+/", result.stderr)
    credential = re.search(r"log in as (\S+) with password (\S+)", result.stderr)
    assert credential, result.stderr
    store = StationStore.open(tmp_path / "station.db")  # the station saw the robot over DDS
    auth = Auth(tmp_path / "station.db")
    try:
        entities = {e.name for e in store.entities("thesis-robot")}
        assert "/usb_cam" in entities
        assert auth.log_in(credential.group(1), credential.group(2), "test").session
    finally:
        auth.close()
        store.close()
    assert (tmp_path / "blackbox.db").exists()
    # --duration 8 of real time: the last step may end a tenth later on a loaded machine
    observed = re.search(r"(\d+\.\d) s observed", (tmp_path / "blackbox.log").read_text())
    assert observed and 8.0 <= float(observed.group(1)) < 9.0, observed


def test_demo_runs_until_interrupted_and_stops_everything_it_started(tmp_path: Path) -> None:
    import socket

    demo = subprocess.Popen([*BLACKBOX, "demo", "--out", str(tmp_path), "--bind",
                             "127.0.0.1:0"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert demo.stderr is not None
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = demo.stderr.readline()
            lines.append(line)
            if "station: http" in line or not line:
                break
        found = re.search(r"http://127\.0\.0\.1:(\d+)/", "".join(lines))
        assert found, "".join(lines)
        time.sleep(3)
        assert demo.poll() is None  # no duration: still running
        demo.send_signal(signal.SIGINT)
        assert demo.wait(timeout=40) == 0, demo.stderr.read()
        with socket.socket() as probe:  # the station went with it
            assert probe.connect_ex(("127.0.0.1", int(found.group(1)))) != 0
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()


def test_log_import_reaches_a_running_black_box_without_restart(tmp_path: Path) -> None:
    db, out = tmp_path / "bb.db", tmp_path / "obs.jsonl"
    proc = subprocess.Popen([*BLACKBOX, "run", "--quiet", "--record", str(db),
                             "--observations", str(out), "--duration", "30"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and (not out.exists() or out.stat().st_size == 0):
            time.sleep(0.1)
        thesis = Path(__file__).resolve().parent.parent / "src/blackbox/configs/thesis.yaml"
        stricter = tmp_path / "stricter.yaml"
        stricter.write_text(thesis.read_text().replace("mean: 15.0, std_deviation: 0.5",
                                                       "mean: 20.0, std_deviation: 0.5"))
        imported = blackbox("log", "import", "--db", str(db), str(stricter),
                            "--note", "tighter signal")
        assert imported.returncode == 0, imported.stderr

        def scores_failing() -> bool:
            return any(r["observer"] == "scores" and r["faulty"] for r in read_records(out))

        while time.monotonic() < deadline + 20 and not scores_failing():
            time.sleep(0.2)
        assert scores_failing(), "the imported thresholds were never applied"
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    events = blackbox("log", "query", "--db", str(db), "--kind", "blackbox_event",
                      "--format", "jsonl")
    kinds = [json.loads(line)["payload"].get("event") for line in events.stdout.splitlines()]
    assert "config_applied" in kinds
