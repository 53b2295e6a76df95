"""The operator's pages at a glance, in Debian's Chromium (Playwright) against the real web
application served by uvicorn in a thread, on a real station database filled through the
store's write API with what the follower stores for a killed ``/usb_cam``:

* the robot page and the events page lead with a one-line headline (what, since when, how
  sure, what to do), the evidence one click away as a list;
* the robot's badge, its row in the entity tree and its fleet row show one status, the
  UCMS rule's, also after a live update;
* the events and logs tables keep their columns and never overflow the viewport at 1,280
  and 768 px, and paginate.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.ids import robot_resource_id
from blackbox.station.auth import Role
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from conftest import wait_until
from station_support import Unreachable, quick_auth

CHROMIUM = Path("/usr/bin/chromium")
playwright_api = pytest.importorskip("playwright.sync_api")
uvicorn = pytest.importorskip("uvicorn")
pytestmark = [
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="needs Debian's chromium (scripts/install-system-deps.sh)"),
    pytest.mark.xdist_group("test_station_web_glance"),  # its module's Chromium: one worker
]

PASSWORD = "station password 1"
ROBOT = "thesis-robot"
CAUSE = ("2 of 14 observations failed: alive on /usb_cam (NOT_AVAILABLE); rate on "
         "/usb_cam/image_raw (TIMEOUT). The observations do not tell node /usb_cam apart "
         "from 1 other explanation of the same size (topic /usb_cam/image_raw); node "
         "/usb_cam ranks first by prior fault probability and closeness to the failed "
         "observations. Each explains every failed observation and agrees with the 12 "
         "healthy ones. No other explanation of the same or smaller size exists.")
FAILURE: dict[str, Any] = {
    "proprietary_fault_code": "NOT_AVAILABLE,TIMEOUT",
    "operator_action": "Stop the mission; the robot drives home on lidar alone",
    "maintenance_action": "Check the camera's USB cable",
    "consequence": "No camera images",
    "complementary": "candidates: {/usb_cam} | {/usb_cam/image_raw}; engine hybrid",
}
VIEWPORTS = [(1280, 860), (768, 1024)]
MOMENT = f"/moment?r={ROBOT}&entity=%2Fusb_cam&since=1&until=4000000000&status=NOT_OPERATIONAL"
"""The page a timeline span opens, over all time (epoch seconds)."""


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[str, StationStore]]:
    path = tmp_path / "station.db"
    store = StationStore.open(path, stale_after=3600.0)  # the robot stays heard throughout
    auth = quick_auth(path)
    auth.add_user("otto", PASSWORD, Role.OPERATOR)
    auth.add_user("ada", PASSWORD, Role.ADMIN)
    fill(store)
    stop = threading.Event()
    server = uvicorn.Server(uvicorn.Config(create_app(auth, store, Unreachable(), stop=stop),
                                           log_level="warning"))
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started and thread.is_alive() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started, "uvicorn did not start within 20 s"
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}", store
    finally:
        stop.set()  # ends the live streams first, else uvicorn waits for them
        server.should_exit = True
        thread.join(timeout=15)
        auth.close()
        store.close()


GREY, GREEN, YELLOW, RED = "#8c959f", "#2da44e", "#d4a72c", "#cf222e"
"""The timeline's colours for UNKNOWN, OPERATIONAL, DEGRADED and NOT_OPERATIONAL."""


def fill(store: StationStore) -> None:
    """A known fault schedule, as the follower records it (statuses at the robot's times):
    every entity heard OPERATIONAL 250 s ago, /odom DEGRADED from 100 to 70 s ago,
    /usb_cam killed 40 s ago (its rate drops from 15 Hz to 0), when the robot entity
    reports the UCMS robot health DEGRADED (one node down); 60 older events of long prose,
    35 log requests."""
    rid = robot_resource_id(ROBOT)
    now = time.time()
    store.heard(rid, now)
    store.put_robot_id(rid, ROBOT)
    first = now - 250
    store.put_entity(rid, 1, name=ROBOT, kind="robot", status="OPERATIONAL", updated=first)
    store.put_entity(rid, 2, name="/usb_cam", kind="node", parent=1, status="OPERATIONAL",
                     updated=first)
    store.put_entity(rid, 3, name="/usb_cam/image_raw", kind="topic", parent=1,
                     status="OPERATIONAL", updated=first)
    store.put_entity(rid, 4, name="/odom", kind="topic", parent=1, status="OPERATIONAL",
                     updated=first)
    store.put_entity(rid, 4, status="DEGRADED", updated=now - 100)
    store.put_entity(rid, 4, status="OPERATIONAL", updated=now - 70)
    store.put_entity(rid, 2, status="NOT_OPERATIONAL", failures=1, cause=CAUSE,
                     actions=FAILURE["operator_action"], updated=now - 40)
    store.put_entity(rid, 1, status="DEGRADED", updated=now - 40)
    store.put_characteristic(rid, 20, entity=2, name="rate /usb_cam/image_raw", unit="Hz",
                             observer="hz")
    for k in range(51):
        t = first + 5 * k
        store.put_value(rid, 20, t, 15.0 if t < now - 40 else 0.0, entity=2)
    for i in range(60):
        store.add_event(rid, now - 3600 + i, "exceedance", dedup=f"x{i}", entity="/odom",
                        text=f"rate /odom: {'a very long message about the rate ' * 12} {i}")
    store.put_diagnosis(rid, ["/usb_cam"], now - 40)
    store.add_event(rid, now - 40, "failure", dedup="f1", entity="/usb_cam", details=FAILURE,
                    text="/usb_cam diagnosed faulty (best of 2 candidate explanations): "
                         + CAUSE)
    assert store.flush(force=True)
    for _ in range(35):
        store.create_log_request(rid, ROBOT, entity="/a/very/long/entity/name/" * 4,
                                 characteristic=None, since=now - 600, until=now, kinds=(),
                                 requested_by="otto")
    store.create_ibit_run(rid, ROBOT, "/usb_cam", "otto")


@pytest.fixture(scope="module")
def chromium() -> Iterator[Any]:
    """One Chromium for the module: starting Playwright's driver and the browser cost about
    2 s of CPU, once per test before. Each test's pages get contexts of their own (cookies,
    storage), as in a browser started for it alone."""
    with playwright_api.sync_playwright() as p:
        started = p.chromium.launch(executable_path=str(CHROMIUM))
        yield started
        started.close()


@pytest.fixture
def browser(chromium: Any) -> Iterator[Any]:
    """The module's Chromium; the contexts a test opened are closed after it."""
    yield chromium
    for context in list(chromium.contexts):
        context.close()


def open_page(browser: Any, url: str, width: int, height: int, user: str = "otto") -> Any:
    page = browser.new_page(base_url=url, viewport={"width": width, "height": height})
    page.set_default_timeout(15_000)
    page.goto("/login")
    page.fill("input[name=username]", user)
    page.fill("input[name=password]", PASSWORD)
    with page.expect_navigation():
        page.click("button[type=submit]")
    return page


OVERFLOW = """() => {
  const width = document.documentElement.clientWidth;
  const wide = [];
  for (const el of document.querySelectorAll('body *')) {
    const box = el.getBoundingClientRect();
    let right = box.right;  // what shows: clipped by every ancestor that hides overflow
    for (let up = el.parentElement; up; up = up.parentElement) {
      if (getComputedStyle(up).overflowX !== 'visible')
        right = Math.min(right, up.getBoundingClientRect().right);
    }
    if (box.width > 0 && right > width + 1) wide.push(el.tagName + '.' + el.className +
      ' right=' + Math.round(right) + ' ' + (el.textContent || '').slice(0, 40));
  }
  return {width: width, scroll: document.documentElement.scrollWidth, wide: wide.slice(0, 5)};
}"""


def laid_out(locator: Any, what: str) -> dict[str, float]:
    """The element's box once it has one: a live view re-rendering its part of the page
    leaves it without a box for a moment."""
    box = wait_until(locator.bounding_box, f"{what} to be laid out")
    assert isinstance(box, dict)
    return box


def assert_fits(page: Any, where: str) -> None:
    found = page.evaluate(OVERFLOW)
    assert found["wide"] == [], f"{where}: elements wider than the viewport: {found}"
    assert found["scroll"] <= found["width"], f"{where}: the page scrolls sideways: {found}"


def test_the_robot_page_leads_with_a_headline_and_the_evidence_is_one_click_away(
        served: tuple[str, StationStore], browser: Any) -> None:
    url, _ = served
    page = open_page(browser, url, 1280, 860)
    page.goto(f"/robot?r={ROBOT}")
    headline = page.locator("#headlines .headline").first
    text = headline.locator(".hl-text").inner_text()
    assert text.startswith("/usb_cam is not running — since "), text
    assert "(one of 2 explanations)" in text
    assert "Stop the mission" in headline.inner_text()
    assert "Check the camera's USB cable" in headline.inner_text()
    headline_box = laid_out(headline, "the headline")
    assert headline_box["y"] < 400, \
        f"the headline is not near the top of the page: {headline_box}"
    evidence = headline.locator("details.hl-evidence")
    failed = evidence.get_by_text("alive on /usb_cam (NOT_AVAILABLE)", exact=True)
    assert not failed.is_visible()  # closed until asked for
    evidence.locator("summary").click()
    failed.wait_for(state="visible")
    items = evidence.locator("dt").all_inner_texts()
    assert items[:3] == ["Failed observations", "Held observations",
                         "Alternative explanations"], items
    assert "{/usb_cam/image_raw}" in evidence.locator("dl").inner_text()

    page.goto("/events")  # the failure's row on the events page: the same headline
    row = page.locator("table.events tr.ev-failure").first
    assert row.locator(".ev-headline").inner_text() == \
        "/usb_cam is not running (one of 2 explanations)"
    assert "Stop the mission" in row.locator(".hl-action").inner_text()


def test_badge_tree_and_fleet_row_show_one_status_also_after_a_live_update(
        served: tuple[str, StationStore], browser: Any) -> None:
    url, store = served
    rid = robot_resource_id(ROBOT)
    page = open_page(browser, url, 1280, 860)

    def shown() -> tuple[str, str, str]:
        page.goto("/")
        fleet = page.locator(f"tr[data-robot='{ROBOT}'] [data-field=status]").inner_text()
        page.goto(f"/robot?r={ROBOT}")
        page.locator("body[data-live=open]").wait_for()
        badge = page.locator("#robot-status").inner_text()
        tree = page.locator("li.entity.kind-robot [data-field=status]").inner_text()
        return badge, tree, fleet

    assert shown() == ("DEGRADED",) * 3  # one node down, as UCMS says
    assert store.robot(ROBOT).reported_status == "DEGRADED"
    # every entity down: NOT_OPERATIONAL everywhere, pushed live to the open page
    for iid in (1, 3, 4):
        store.put_entity(rid, iid, status="NOT_OPERATIONAL")
    assert store.flush(force=True)
    page.locator("#robot-status.h-not-operational").wait_for()
    page.locator("li.entity.kind-robot.h-not-operational").wait_for()
    assert page.locator("li.entity.kind-robot [data-field=status]").inner_text() == \
        page.locator("#robot-status").inner_text() == "NOT_OPERATIONAL"
    assert shown() == ("NOT_OPERATIONAL",) * 3


def test_the_timeline_draws_the_fault_schedule_and_a_span_opens_its_events_and_charts(
        served: tuple[str, StationStore], browser: Any) -> None:
    url, store = served
    page = open_page(browser, url, 1280, 860)
    page.goto(f"/robot?r={ROBOT}&zoom=5m")
    lanes = page.locator("#timeline svg g.lane")
    names = [lanes.nth(i).get_attribute("data-entity") for i in range(lanes.count())]
    assert names == [ROBOT, "/usb_cam", "/odom", "/usb_cam/image_raw"], names  # tree order
    def fills(lane: str) -> list[str | None]:
        spans = page.locator(f"#timeline g.lane[data-entity='{lane}'] rect.span")
        return [spans.nth(i).get_attribute("fill") for i in range(spans.count())]

    # the schedule's statuses in order, grey before the station first heard them
    assert fills("/usb_cam") == [GREY, GREEN, RED]
    assert fills("/odom") == [GREY, GREEN, YELLOW, GREEN]
    assert fills("/usb_cam/image_raw") == [GREY, GREEN]
    assert fills(ROBOT) == [GREY, GREEN, YELLOW, GREEN, YELLOW]  # its badge's rule
    assert page.locator("#robot-status").inner_text() == "DEGRADED"  # = the lane's end
    def seconds(lane: str) -> list[float]:
        """The lane's spans in seconds (the window is 300 s, however late it is drawn:
        the load on a shared machine may delay the page by seconds)."""
        spans = page.locator(f"#timeline g.lane[data-entity='{lane}'] rect.span")
        widths = [float(spans.nth(i).get_attribute("width") or 0)
                  for i in range(spans.count())]
        return [300 * w / sum(widths) for w in widths]

    grey, green, red = seconds("/usb_cam")
    assert abs(green - 210) < 1.5, (grey, green, red)  # heard 250 s ago, killed 40 s ago
    assert abs(grey + red - 90) < 1.5, (grey, green, red)
    assert abs(seconds("/odom")[2] - 30) < 1.5  # DEGRADED for 30 s
    page.locator("body[data-live=open]").wait_for()  # live: a new failure is drawn
    rid = robot_resource_id(ROBOT)
    store.put_entity(rid, 4, status="NOT_OPERATIONAL", updated=time.time() - 20)
    store.add_event(rid, time.time() - 20, "failure", dedup="f2", entity="/odom",
                    text="/odom diagnosed faulty")
    assert store.flush(force=True)
    page.locator(f"#timeline g.lane[data-entity='/odom'] rect.span[fill='{RED}']"
                 ).wait_for()
    cam = page.locator("#timeline g.lane[data-entity='/usb_cam'] rect.span")
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    cam.last.click()  # the red span: the events and charts of that entity and moment
    page.wait_for_url("**/moment?**")
    assert "entity=%2Fusb_cam" in page.url, page.url
    assert page.locator("#moment-status").inner_text() == "NOT_OPERATIONAL"
    assert page.locator("table.events tbody tr.ev-failure").count() == 1
    chart = page.locator("#moment-charts figure.chart[data-char='20']")
    assert "rate /usb_cam/image_raw" in chart.locator("figcaption").inner_text()
    chart.locator("canvas").first.wait_for()  # drawn by uPlot
    drawn = page.evaluate("""() => {
      const data = JSON.parse(document.getElementById('series').dataset.series)['20'];
      return {n: data[0].length, first: data[1][0], last: data[1][data[1].length - 1]};
    }""")
    assert drawn["n"] >= 10 and drawn["first"] == 15.0 and drawn["last"] == 0.0, drawn
    shaded = page.evaluate("""() => {  // the clicked span is shaded on the chart
      const c = document.querySelector("#moment-charts figure.chart canvas");
      const x = c.width - 20, y = Math.round(c.height / 2);
      return Array.from(c.getContext("2d").getImageData(x, y, 1, 1).data);
    }""")
    assert shaded[3] > 0 and shaded[0] > shaded[2], shaded  # reddish, not blank
    assert errors == [], errors
    page.locator("#moment-events").click()  # the filterable events page of that moment
    page.wait_for_url("**/events?**")
    assert "entity=%2Fusb_cam" in page.url
    assert page.locator("table.events tbody tr.ev-failure").count() == 1


def test_the_entity_page_has_its_own_timeline_exported_as_svg_and_png(
        served: tuple[str, StationStore], browser: Any, tmp_path: Path) -> None:
    url, _ = served
    page = browser.new_page(base_url=url, accept_downloads=True,
                            viewport={"width": 1280, "height": 860})
    page.set_default_timeout(15_000)
    page.goto("/login")
    page.fill("input[name=username]", "otto")
    page.fill("input[name=password]", PASSWORD)
    with page.expect_navigation():
        page.click("button[type=submit]")
    page.goto(f"/entity?r={ROBOT}&id=2&zoom=5m")
    lanes = page.locator("#timeline svg g.lane")
    assert [lanes.nth(i).get_attribute("data-entity") for i in range(lanes.count())] == \
        [ROBOT, "/usb_cam"]
    with page.expect_download() as svg_file:
        page.click("#timeline-svg")
    svg_path = tmp_path / "timeline.svg"
    svg_file.value.save_as(svg_path)
    root = ET.parse(svg_path).getroot()
    lanes_in_file = root.findall("{http://www.w3.org/2000/svg}g")
    assert [g.get("data-entity") for g in lanes_in_file] == [ROBOT, "/usb_cam"]
    assert root.findall(".//{http://www.w3.org/2000/svg}a") == []  # stands alone
    with page.expect_download() as png_file:
        page.click("#timeline-png")
    png_path = tmp_path / "timeline.png"
    png_file.value.save_as(png_path)
    data = png_path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", data[:16]
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (2 * int(root.get("width") or 0),
                               2 * int(root.get("height") or 0))


@pytest.mark.parametrize(("width", "height"), VIEWPORTS)
def test_tables_keep_their_columns_and_no_page_is_wider_than_the_viewport(
        served: tuple[str, StationStore], browser: Any, width: int, height: int) -> None:
    url, _ = served
    page = open_page(browser, url, width, height)
    for path in ("/", f"/robot?r={ROBOT}", "/events", "/logs", f"/entity?r={ROBOT}&id=2",
                 "/alerts", "/tokens", MOMENT):
        page.goto(path)
        assert_fits(page, f"{path} at {width} px")
    page.goto("/events")
    header = page.locator("table.events th", has_text="Acknowledged")
    line = laid_out(page.locator("table.events th", has_text="Time"), "the Time header")
    box = laid_out(header, "the Acknowledged header")
    assert box["height"] <= line["height"] + 1, \
        f"the Acknowledged header wraps: {box} vs one line {line}"
    assert page.locator("table.events tbody tr").count() == 50  # a page of 50
    older = page.locator("a", has_text="Older events")
    with page.expect_navigation():
        older.click()
    assert page.locator("table.events tbody tr").count() == 11
    assert page.locator("a", has_text="Newest events").count() == 1
    # a long text is one line, its full text on demand
    cell = page.locator("table.events tr.ev-exceedance td.what").first
    one_line = laid_out(cell, "a long text's cell")
    assert one_line["height"] < 40, one_line
    cell.locator("summary").click()
    assert "a very long message about the rate" in cell.locator("details p").inner_text()
    assert_fits(page, f"/events with a text opened at {width} px")

    page.goto("/logs")
    assert page.locator("table.logs tbody tr").count() == 30
    with page.expect_navigation():
        page.locator("a", has_text="Older requests").click()
    assert page.locator("table.logs tbody tr").count() == 5


AXE = "/static/vendor/axe-core/axe.min.js"
AXE_RUN = """async () => {
  const found = await axe.run(document, {resultTypes: ['violations']});
  return found.violations.filter(v => v.impact === 'serious' || v.impact === 'critical')
    .map(v => v.id + ': ' + v.help + ' @ ' + v.nodes.slice(0, 3).map(n => n.target.join(' '))
    .join(' | '));
}"""
PAGES = ["/", f"/robot?r={ROBOT}", f"/entity?r={ROBOT}&id=2", "/events", "/logs", "/logs/1",
         "/ibit/1", "/users", "/alerts", "/tokens", "/logs/999999", MOMENT]


@pytest.mark.parametrize(("width", "height"), VIEWPORTS)
def test_axe_finds_no_serious_accessibility_violation_on_any_page(
        served: tuple[str, StationStore], browser: Any, width: int, height: int) -> None:
    url, _ = served
    page = browser.new_page(base_url=url, viewport={"width": width, "height": height})
    page.set_default_timeout(15_000)
    found: dict[str, list[str]] = {}
    page.goto("/login")
    page.add_script_tag(url=AXE)  # from this origin: the CSP allows it
    found["/login"] = page.evaluate(AXE_RUN)
    page = open_page(browser, url, width, height, "ada")
    for path in PAGES:
        page.goto(path)
        page.add_script_tag(url=AXE)
        found[path] = page.evaluate(AXE_RUN)
    serious = {k: v for k, v in found.items() if v}
    assert serious == {}, "\n".join(f"{k}: {v}" for k, v in serious.items())
