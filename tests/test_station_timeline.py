"""The health timeline: lanes rebuilt from stored events for a known fault schedule, drawn
as an SVG whose spans have the status colours and link to the events of that moment."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.record.store import Row, Store
from blackbox.station.timeline import COLOURS, Happening, Span, build, svg

T0 = 1_790_000_000.0
NS = {"s": "http://www.w3.org/2000/svg"}
SCHEDULE = [Happening(T0 + 30, "failure", "/usb_cam", acknowledged_at=T0 + 35),
            Happening(T0 + 45, "rectification", "/usb_cam"),
            Happening(T0 + 50, "exceedance", "/odom"),
            Happening(T0 + 70, "failure", "/odom"),
            Happening(T0 + 80, "failure", "/not/listed")]


def test_an_entity_is_red_from_its_failure_to_its_rectification() -> None:
    robot, cam, odom = build("thesis", ["/usb_cam", "/odom"], SCHEDULE, T0, T0 + 100)
    assert cam.spans == (Span(T0, T0 + 30, "OPERATIONAL"), Span(T0 + 30, T0 + 45,
                                                                "NOT_OPERATIONAL"),
                         Span(T0 + 45, T0 + 100, "OPERATIONAL"))
    assert [(m.time, m.kind) for m in cam.marks] == [(T0 + 35, "acknowledged")]
    assert odom.spans[-1] == Span(T0 + 70, T0 + 100, "NOT_OPERATIONAL")  # not cleared yet
    assert [(m.time, m.kind) for m in odom.marks] == [(T0 + 50, "exceedance")]
    assert robot.entity == "thesis"
    assert [(s.start - T0, s.end - T0, s.status) for s in robot.spans] == [
        (0, 30, "OPERATIONAL"), (30, 45, "NOT_OPERATIONAL"), (45, 70, "OPERATIONAL"),
        (70, 100, "NOT_OPERATIONAL")]


def test_a_failure_before_the_window_keeps_its_lane_red_from_the_start() -> None:
    _, cam = build("thesis", ["/usb_cam"], [], T0, T0 + 60, {"/usb_cam": "NOT_OPERATIONAL"})
    assert cam.spans == (Span(T0, T0 + 60, "NOT_OPERATIONAL"),)


def test_the_svg_has_one_lane_per_entity_in_the_status_colours_linking_to_events() -> None:
    lanes = build("thesis", ["/usb_cam", "/odom"], SCHEDULE, T0, T0 + 100)
    root = ET.fromstring(svg(lanes, T0, T0 + 100, robot_ref="thesis"))
    groups = root.findall("s:g", NS)
    assert [g.get("data-entity") for g in groups] == ["thesis", "/usb_cam", "/odom"]
    cam_rects = groups[1].findall(".//s:rect[@class]", NS)
    spans = [r for r in cam_rects if "span" in (r.get("class") or "")]
    assert [r.get("fill") for r in spans] == [COLOURS["OPERATIONAL"],
                                               COLOURS["NOT_OPERATIONAL"],
                                               COLOURS["OPERATIONAL"]]
    red_width = float(spans[1].get("width") or 0)
    whole = sum(float(r.get("width") or 0) for r in spans)
    assert abs(red_width / whole - 0.15) < 0.01  # 15 s of 100
    link = groups[1].findall("s:a", NS)[1].get("href") or ""
    assert link.startswith("/events?") and "entity=%2Fusb_cam" in link
    assert "since=2026-09-21T14%3A13%3A50" in link


def test_names_are_escaped_and_a_standalone_picture_has_no_links() -> None:
    evil = "<script>alert(1)</script>"
    lanes = build("bot", [evil], [Happening(T0 + 1, "failure", evil)], T0, T0 + 10)
    text = svg(lanes, T0, T0 + 10)
    assert "<script>" not in text
    root = ET.fromstring(text)
    assert root.findall(".//s:a", NS) == []
    assert root.findall("s:g", NS)[1].get("data-entity") == evil


def test_blackbox_log_export_timeline_draws_the_robots_own_record(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An incident report without a station: the same picture from the robot's health log,
    older rows (components and category) and newer ones (named events) alike."""
    path = tmp_path / "log.db"
    cam = ("/usb_cam/image_raw", "hz", '{"topic":"/usb_cam/image_raw"}')
    with Store.open(path) as store:
        store.append([
            Row(T0, "observation", cam, 0, {"values": {"period": 0.0667}}),
            Row(T0 + 30, "failure", None, None, {"components": ["/usb_cam"],
                                                  "category": "detection"}),
            Row(T0 + 40, "exceedance", cam, -2, {"values": {"period": 0.5}}),
            Row(T0 + 45, "failure", None, None, {"events": [
                {"kind": "rectification", "entity": "/usb_cam", "id": "b-2"}]}),
            Row(T0 + 100, "observation", cam, 0, {"values": {"period": 0.0667}}),
        ])
    out = tmp_path / "incident.svg"
    assert main(["log", "export", "--db", str(path), "--timeline", "-o", str(out)]) == 0
    root = ET.parse(out).getroot()
    groups = root.findall("s:g", NS)
    assert [g.get("data-entity") for g in groups][1:] == ["/usb_cam", "/usb_cam/image_raw"]
    cam_spans = [r for r in groups[1].findall("s:rect", NS) if "span" in (r.get("class") or "")]
    assert [r.get("fill") for r in cam_spans] == [COLOURS["OPERATIONAL"],
                                                   COLOURS["NOT_OPERATIONAL"],
                                                   COLOURS["OPERATIONAL"]]
    widths = [float(r.get("width") or 0) for r in cam_spans]
    assert abs(widths[1] / sum(widths) - 0.15) < 0.01  # 15 s of the log's 100
    ticks = groups[2].findall("s:rect[@class='mark m-exceedance']", NS)
    assert len(ticks) == 1
    assert "drew 3 lanes from 5 entries" in capsys.readouterr().err


def test_timeline_export_refuses_other_formats_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "log.db"
    with Store.open(path) as store:
        store.append([Row(T0, "failure", None, None, {"components": ["/a"]})])
    assert main(["log", "export", "--db", str(path), "--timeline", "-o",
                 str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "--timeline writes SVG only" in err and "Traceback" not in err
