"""The fleet page with 1,000 robots: counts by status at the top, worst first, filter and
search by robot, site and status, 50 robots a page, never wider than the viewport; the same
rows in the page's live state. Pure ordering and filtering on the view; the page in Debian's
Chromium (Playwright) against the real web application on a real station database.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.ids import robot_resource_id
from blackbox.station.alerts.rules import AlertConfig
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Role
from blackbox.station.fleet_view import FleetQuery, SiteMap, fleet_page
from blackbox.station.store import RobotSummary, StationStore
from blackbox.station.web.app import create_app
from conftest import wait_until
from fleet_support import SITES, fill_fleet, robot_name, status_of
from station_support import Unreachable, quick_auth

CHROMIUM = Path("/usr/bin/chromium")
PASSWORD = "station password 1"
ROBOTS = 1000
EXPECTED = {"NOT_OPERATIONAL": 20, "DEGRADED": 100, "UNKNOWN": 40, "OPERATIONAL": 840}


def summary(name: str, status: str, unacknowledged: int = 0, failing: int = 0) -> RobotSummary:
    return RobotSummary(robot_resource_id(name), name, name, status, status, time.time(),
                        status == "UNKNOWN", True, 4, failing, unacknowledged, ())


# ---- the view (pure) ------------------------------------------------------------------------


def test_worst_first_then_most_alarms_then_most_faulty_entities_then_name() -> None:
    robots = [summary("a", "OPERATIONAL"), summary("b", "UNKNOWN"),
              summary("c", "DEGRADED", failing=1), summary("d", "DEGRADED", failing=2),
              summary("e", "DEGRADED", unacknowledged=1), summary("f", "NOT_OPERATIONAL")]
    view = fleet_page(robots, SiteMap().site_of, FleetQuery())
    assert [r.robot.name for r in view.rows] == ["f", "e", "d", "c", "b", "a"]
    assert dict(view.counts) == {"NOT_OPERATIONAL": 1, "DEGRADED": 3, "UNKNOWN": 1,
                                 "OPERATIONAL": 1}


def test_search_matches_part_of_a_robot_or_a_site_in_any_case_and_counts_stay_whole() -> None:
    robots = [summary(robot_name(i), status_of(i)) for i in range(1000)]
    sites = SiteMap(SITES)
    by_robot = fleet_page(robots, sites.site_of, FleetQuery.of(search="TUG-012"))
    assert sorted(r.robot.name for r in by_robot.rows) == [f"tug-012{d}" for d in range(10)]
    assert by_robot.total == 1000 and sum(by_robot.counts.values()) == 1000
    by_site = fleet_page(robots, sites.site_of, FleetQuery.of(search="Harb"))
    assert by_site.matched == 600 and {r.site for r in by_site.rows} == {"harbour"}
    exact_site = fleet_page(robots, sites.site_of, FleetQuery.of(site="ward-b",
                                                                 status="degraded"))
    assert exact_site.matched == 20  # robots 200-399, every 10th degraded
    assert all(r.site == "ward-b" and r.robot.status == "DEGRADED" for r in exact_site.rows)
    assert by_site.sites == ("depot-a", "harbour", "ward-b")


def test_pages_of_fifty_and_a_page_beyond_the_last_shows_the_last() -> None:
    robots = [summary(robot_name(i), "OPERATIONAL") for i in range(120)]
    view = fleet_page(robots, SiteMap().site_of, FleetQuery.of(page=2))
    assert (view.page, view.pages, len(view.rows)) == (2, 3, 20)
    assert view.rows[0].robot.name == "tug-0100"
    assert fleet_page(robots, SiteMap().site_of, FleetQuery.of(page=99)).page == 2
    with pytest.raises(ValueError, match="unknown status 'GREEN'"):
        FleetQuery.of(status="green")


# ---- the page, 1,000 robots, real HTTP and Chromium ------------------------------------------


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, StationStore]]:
    uvicorn = pytest.importorskip("uvicorn")
    path = tmp_path_factory.mktemp("fleet") / "station.db"
    store = StationStore.open(path, stale_after=600.0)
    auth = quick_auth(path)
    auth.add_user("vera", PASSWORD, Role.VIEWER)
    fill_fleet(store, ROBOTS)
    alerts = AlertService(store, path, AlertConfig(file="alerts.yaml", sites=SITES))
    stop = threading.Event()
    server = uvicorn.Server(uvicorn.Config(
        create_app(auth, store, Unreachable(), stop=stop, alerts=alerts), log_level="warning"))
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    wait_until(lambda: server.started or not thread.is_alive(), "uvicorn to start", 20)
    assert server.started, "uvicorn stopped while starting"
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}", store
    finally:
        stop.set()
        server.should_exit = True
        thread.join(timeout=15)
        auth.close()
        store.close()


OVERFLOW = """() => {
  const width = document.documentElement.clientWidth;
  const wide = [];
  for (const el of document.querySelectorAll('body *')) {
    const box = el.getBoundingClientRect();
    let right = box.right;
    for (let up = el.parentElement; up; up = up.parentElement) {
      if (getComputedStyle(up).overflowX !== 'visible')
        right = Math.min(right, up.getBoundingClientRect().right);
    }
    if (box.width > 0 && right > width + 1) wide.push(el.tagName + '.' + el.className +
      ' right=' + Math.round(right));
  }
  return {width: width, scroll: document.documentElement.scrollWidth, wide: wide.slice(0, 5)};
}"""


def logged_in(browser: Any, url: str, width: int) -> Any:
    page = browser.new_page(base_url=url, viewport={"width": width, "height": 900})
    page.set_default_timeout(15_000)
    page.goto("/login")
    page.fill("input[name=username]", "vera")
    page.fill("input[name=password]", PASSWORD)
    with page.expect_navigation():
        page.click("button[type=submit]")
    return page


def counts_shown(page: Any) -> dict[str, int]:
    return {s: int(page.locator(f"[data-count={s}] [data-field=count]").inner_text())
            for s in EXPECTED}


def statuses_shown(page: Any) -> list[str]:
    return [str(s) for s in page.locator("table.fleet [data-field=status]").all_inner_texts()]


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium")
@pytest.mark.xdist_group("fleet-page")
def test_a_thousand_robots_counts_worst_first_filters_pages_and_fits_the_viewport(
        served: tuple[str, StationStore]) -> None:
    playwright_api = pytest.importorskip("playwright.sync_api")
    url, store = served
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM))
        for width in (1280, 768):
            page = logged_in(browser, url, width)
            page.goto("/")
            assert counts_shown(page) == EXPECTED
            assert page.locator("[data-field=total]").inner_text() == str(ROBOTS)
            shown = statuses_shown(page)
            assert shown == ["NOT_OPERATIONAL"] * 20 + ["DEGRADED"] * 30, shown
            found = page.evaluate(OVERFLOW)
            assert found["wide"] == [] and found["scroll"] <= found["width"], \
                f"at {width} px elements are wider than the viewport: {found}"
            page.close()

        page = logged_in(browser, url, 1280)
        page.goto("/")
        with page.expect_navigation():  # page 2: the rest of the degraded
            page.locator("nav.pager a[rel=next]").click()
        assert statuses_shown(page) == ["DEGRADED"] * 50
        assert "page 2 of 20" in page.locator("nav.pager").inner_text()

        page.goto("/")
        page.select_option("select[name=site]", "ward-b")
        page.select_option("select[name=status]", "UNKNOWN")
        with page.expect_navigation():
            page.click(".fleet-filter button[type=submit]")
        names = page.locator("table.fleet tbody tr a").all_inner_texts()
        assert names == [robot_name(i) for i in range(200, 400) if status_of(i) == "UNKNOWN"]
        assert counts_shown(page) == EXPECTED  # the headline counts the whole fleet

        page.fill("input[name=search]", "tug-0042")
        page.select_option("select[name=site]", "")
        page.select_option("select[name=status]", "")
        with page.expect_navigation():
            page.click(".fleet-filter button[type=submit]")
        assert page.locator("table.fleet tbody tr").count() == 1
        page.locator("body[data-live=open]").wait_for()

        # a fault on the robot shown turns its row red in place, and the counts follow
        rid = robot_resource_id("tug-0042")
        for iid in range(1, 8):
            store.put_entity(rid, iid, status="NOT_OPERATIONAL")
        store.heard(rid, time.time())
        assert store.flush(force=True)
        page.locator("tr[data-robot=tug-0042] .badge.h-not-operational").wait_for()
        page.locator("[data-count=NOT_OPERATIONAL] [data-field=count]",
                     has_text="21").wait_for()
        browser.close()
