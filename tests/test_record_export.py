"""Getting the log out (JSON lines, CSV, MCAP) and the `blackbox log` commands."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.record.export import ENTRY_SCHEMA, read_jsonl, write_csv, write_jsonl
from blackbox.record.store import Row, Store

CAM = ("/usb_cam/image_raw", "hz", '{"topic":"/usb_cam/image_raw"}')
NODE = ("/usb_cam", "activated", '{"node":"/usb_cam"}')


@pytest.fixture
def log(tmp_path: Path) -> Path:
    path = tmp_path / "log.db"
    with Store.open(path) as store:
        store.append([
            Row(100.0, "observation", CAM, 0, {"values": {"period": 0.0667}, "states": [1]}),
            Row(160.0, "sample", CAM, 0, {"values": {"period": 0.0668}, "states": [1]}),
            Row(170.0, "exceedance", CAM, -2, {"values": {"period": 0.5}, "states": []}),
            Row(171.0, "observation", NODE, -1, {"message": "dead, no answer"}),
            Row(172.0, "failure", None, None, {"components": ["/usb_cam"],
                                                "category": "detection"}),
        ])
    return path


def test_jsonl_round_trip(log: Path) -> None:
    with Store.open(log, readonly=True) as store:
        entries = list(store.query())
    buf = io.StringIO()
    assert write_jsonl(entries, buf) == 5
    assert read_jsonl(buf.getvalue().splitlines()) == entries


def test_csv_has_one_row_per_entry_with_payload_as_json(log: Path) -> None:
    with Store.open(log, readonly=True) as store:
        buf = io.StringIO()
        write_csv(store.query(kinds=["exceedance"]), buf)
    rows = list(csv.reader(io.StringIO(buf.getvalue())))
    assert rows[0] == ["id", "time", "kind", "entity", "characteristic", "code", "payload"]
    assert rows[1][:6] == ["3", "170.0", "exceedance", "/usb_cam/image_raw", "hz", "-2"]
    assert json.loads(rows[1][6]) == {"values": {"period": 0.5}, "states": []}


def test_mcap_export_has_a_json_schema_channel_per_kind(log: Path, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    out = tmp_path / "log.mcap"
    assert main(["log", "export", "--db", str(log), "-o", str(out)]) == 0
    with out.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        (schema,) = summary.schemas.values()
        assert schema.encoding == "jsonschema"
        assert json.loads(schema.data) == ENTRY_SCHEMA
        topics = sorted(ch.topic for ch in summary.channels.values())
        assert topics == ["/blackbox/exceedance", "/blackbox/failure", "/blackbox/observation",
                          "/blackbox/sample"]
        assert {ch.message_encoding for ch in summary.channels.values()} == {"json"}
        msgs = [(ch.topic, msg.log_time, json.loads(msg.data))
                for _, ch, msg in reader.iter_messages()]
    assert msgs[2][0] == "/blackbox/exceedance"
    assert msgs[2][1] == 170_000_000_000
    assert msgs[2][2]["payload"]["values"]["period"] == 0.5


def test_query_command_filters(log: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["log", "query", "--db", str(log), "--entity", "/usb_cam*", "--since", "165",
                 "--format", "jsonl"]) == 0
    got = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(e["id"], e["kind"], e["entity"]) for e in got] == \
        [(3, "exceedance", "/usb_cam/image_raw"), (4, "observation", "/usb_cam")]
    assert main(["log", "query", "--db", str(log), "--kind", "failure"]) == 0
    out = capsys.readouterr().out
    assert "failure" in out and "components=['/usb_cam']" in out


def test_query_command_errors_are_clear(log: Path, tmp_path: Path,
                                        capsys: pytest.CaptureFixture) -> None:
    assert main(["log", "query", "--db", str(log), "--kind", "crash"]) == 2
    assert "unknown kind 'crash'" in capsys.readouterr().err
    assert main(["log", "query", "--db", str(tmp_path / "nope.db")]) == 1
    assert "no such health log" in capsys.readouterr().err
    assert main(["log", "query", "--db", str(log), "--since", "yesterday"]) == 2
    assert "not a time: 'yesterday'" in capsys.readouterr().err


def test_export_csv_to_file_with_time_range(log: Path, tmp_path: Path) -> None:
    out = tmp_path / "x.csv"
    assert main(["log", "export", "--db", str(log), "--until", "160", "-o", str(out)]) == 0
    rows = list(csv.reader(out.open()))
    assert [r[0] for r in rows[1:]] == ["1", "2"]


def test_purge_needs_confirmation_then_records_itself(log: Path,
                                                      capsys: pytest.CaptureFixture,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sys.stdin", io.StringIO("no\n"))
    assert main(["log", "purge", "--db", str(log)]) == 2  # not a terminal, no --yes
    assert "needs confirmation" in capsys.readouterr().err
    snapshots = log.with_name("log.db.snapshots")
    snapshots.mkdir()
    (snapshots / "r1-x.bag").write_bytes(b"bag")
    (snapshots / "mine.bag").write_bytes(b"a user's own bag, not the recorder's")
    with Store.open(log) as store:
        store.register_snapshot("r1-x.bag", 1.0)
    assert main(["log", "purge", "--db", str(log), "--yes", "--by", "depot"]) == 0
    assert "purged 5 entries and 1 snapshot files" in capsys.readouterr().out
    with Store.open(log, readonly=True) as store:
        (entry,) = store.query()
    assert entry.kind == "blackbox_event"
    assert entry.payload == {"event": "purge", "deleted": 5, "by": "depot",
                             "kept_config_entry": None}
    assert [p.name for p in snapshots.iterdir()] == ["mine.bag"]


def test_db_from_the_configuration(log: Path, tmp_path: Path,
                                   capsys: pytest.CaptureFixture) -> None:
    cfg = tmp_path / "bb.yaml"
    cfg.write_text("observers: []\nrecorder:\n  path: log.db\n")
    assert main(["log", "query", "--config", str(cfg), "--kind", "failure",
                 "--format", "jsonl"]) == 0
    assert json.loads(capsys.readouterr().out)["id"] == 5
