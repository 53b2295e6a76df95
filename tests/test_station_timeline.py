"""The health timeline: lanes rebuilt from stored events for a known fault schedule, drawn
as an SVG whose spans have the status colours and link to the events of that moment."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.record.store import Row, Store
from blackbox.station.timeline import COLOURS, Happening, Recorded, Span, build, svg

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
    link = groups[1].findall("s:a", NS)[1].get("href") or ""  # the events and charts page
    assert link.startswith("/moment?r=thesis&") and "entity=%2Fusb_cam" in link
    assert "since=2026-09-21T14%3A13%3A50" in link and "status=NOT_OPERATIONAL" in link


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


def write_incident_log(path: Path) -> None:
    """/usb_cam fails at 30 s and is rectified at 45 s of a 100 s log; its image topic
    exceeds its threshold at 40 s."""
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


def rgb(colour: str) -> tuple[int, int, int]:
    return (int(colour[1:3], 16), int(colour[3:5], 16), int(colour[5:7], 16))


@pytest.mark.parametrize("how", [["incident.png"], ["--format", "png", "incident"]])
def test_blackbox_log_export_timeline_draws_a_png_without_a_browser(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], how: list[str]) -> None:
    """The PNG is the SVG's picture at twice its size: a lane's colour at a known moment is
    the status it had then (the x axis maps the log's 100 s onto 800 px after 190 px of
    labels; lane n's middle is 22 + 20 n + 10 px down)."""
    from PIL import Image

    path = tmp_path / "log.db"
    write_incident_log(path)
    out = tmp_path / how[-1]
    assert main(["log", "export", "--db", str(path), "--timeline",
                 *how[:-1], "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = Image.open(out).convert("RGB")
    assert image.size == (2000, 2 * (22 + 20 * 3 + 6))

    def at(lane: int, second: float) -> tuple[int, int, int]:
        x = 2 * (190 + second / 100 * 800)
        y = 2 * (22 + 20 * lane + 10)
        return image.getpixel((round(x), y))  # type: ignore[return-value]

    for lane in (0, 1):  # the robot and /usb_cam: green, red 30-45 s, green again
        assert at(lane, 10) == rgb(COLOURS["OPERATIONAL"])
        assert at(lane, 37) == rgb(COLOURS["NOT_OPERATIONAL"])
        assert at(lane, 60) == rgb(COLOURS["OPERATIONAL"])
    assert at(2, 40) == rgb(COLOURS["DEGRADED"])  # the exceedance's yellow tick
    assert at(2, 60) == rgb(COLOURS["OPERATIONAL"])
    labels = image.crop((0, 2 * 22, 2 * 190, 2 * 42)).getcolors(maxcolors=100000) or []
    assert len(labels) > 2, "the robot lane's label is not drawn"
    assert "(png)" in capsys.readouterr().err


def test_timeline_export_refuses_other_formats_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "log.db"
    with Store.open(path) as store:
        store.append([Row(T0, "failure", None, None, {"components": ["/a"]})])
    assert main(["log", "export", "--db", str(path), "--timeline", "-o",
                 str(tmp_path / "x.txt")]) == 2
    err = capsys.readouterr().err
    assert "--timeline writes SVG or PNG, not txt" in err and "Traceback" not in err
    assert main(["log", "export", "--db", str(path), "--timeline", "--format", "png", "-o",
                 str(tmp_path / "x.svg")]) == 2
    assert "--format png does not match the output x.svg" in capsys.readouterr().err
    assert main(["log", "export", "--db", str(path), "--format", "png", "-o",
                 str(tmp_path / "x.png")]) == 2
    assert "add --timeline" in capsys.readouterr().err


def test_kept_statuses_draw_degraded_spans_and_the_robots_own_status() -> None:
    """On the station the lanes come from the statuses it kept: /odom DEGRADED from 20 s,
    /usb_cam unknown until first heard at 10 s; the robot lane is the robot's derived
    status, and an unkept entity still comes from its events."""
    robot, cam, odom, imu = build(
        "thesis", ["/usb_cam", "/odom", "/imu"],
        [Happening(T0 + 30, "failure", "/usb_cam"), Happening(T0 + 50, "failure", "/imu")],
        T0, T0 + 100,
        recorded={"/usb_cam": Recorded("UNKNOWN", [(T0 + 10, "OPERATIONAL"),
                                                   (T0 + 31, "NOT_OPERATIONAL")]),
                  "/odom": Recorded("OPERATIONAL", [(T0 + 20, "DEGRADED")])},
        robot_recorded=Recorded("OPERATIONAL", [(T0 + 20, "DEGRADED")]))
    assert cam.spans == (Span(T0, T0 + 10, "UNKNOWN"), Span(T0 + 10, T0 + 31, "OPERATIONAL"),
                         Span(T0 + 31, T0 + 100, "NOT_OPERATIONAL"))  # not the event's 30 s
    assert odom.spans == (Span(T0, T0 + 20, "OPERATIONAL"), Span(T0 + 20, T0 + 100,
                                                                 "DEGRADED"))
    assert imu.spans[-1] == Span(T0 + 50, T0 + 100, "NOT_OPERATIONAL")
    assert robot.spans == (Span(T0, T0 + 20, "OPERATIONAL"), Span(T0 + 20, T0 + 100,
                                                                  "DEGRADED"))
    root = ET.fromstring(svg([robot, cam, odom, imu], T0, T0 + 100))
    fills = [r.get("fill") for r in root.findall("s:g", NS)[2].findall("s:rect", NS)]
    assert fills == [COLOURS["OPERATIONAL"], COLOURS["DEGRADED"]]
