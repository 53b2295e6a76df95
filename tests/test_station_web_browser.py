"""The station in a real browser: Debian's Chromium driven by Playwright against a real
``blackbox station`` process following a real ``blackbox run --dds`` of the simulated
thesis robot (Cyclone DDS on loopback), with a fault schedule that kills ``/usb_cam``.

The screenshots in README.md and docs/station.md are taken here: with
``STATION_SCREENSHOTS=1`` they are written to docs/img/station-*.png, otherwise to the
test's temporary directory (so a test run leaves the work tree as it was).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import pytest

from blackbox.transport.auth import station_trusted_by
from conftest import ROOT, wait_for
from isolation import fresh_domain

CHROMIUM = Path("/usr/bin/chromium")
playwright_api = pytest.importorskip("playwright.sync_api")
pytestmark = [
    pytest.mark.xdist_group("test_station_web_browser"),  # its module fixture: one worker
    pytest.mark.dds, pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="needs Debian's chromium (scripts/install-system-deps.sh)"),
]

BLACKBOX = [sys.executable, "-m", "blackbox"]
IMG = ROOT / "docs" / "img" if os.environ.get("STATION_SCREENSHOTS") == "1" else None
FAULT_START, FAULT_END, RUN_FOR = 30.0, 45.0, 150.0
PASSWORDS = {"ada": "admin password 1", "otto": "operator password 1",
             "vera": "viewer password 1", "tess": "operator password 2"}
ROLES = {"ada": "admin", "otto": "operator", "vera": "viewer", "tess": "operator"}
# The first throttled wait: long enough that a loaded machine's slow page loads stay inside
# it, so "the right password must wait too" is tested, not raced. Only "tess" is throttled.
LOGIN_BACKOFF = 120.0


@dataclass
class Fleet:
    url: str
    record: Path
    started: float
    tmp: Path

    def shot(self, page: object, name: str, full_page: bool = False) -> None:
        folder = IMG if IMG is not None else self.tmp
        folder.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(folder / f"station-{name}.png"),  # type: ignore[attr-defined]
                        full_page=full_page)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _started(record: Path) -> list[float]:
    """The time of the black box's start event in its record (empty until it is there)."""
    from blackbox.record import Store
    from blackbox.record.store import StorageError

    if not record.exists():
        return []
    try:
        robot = Store.open(record, readonly=True, check=False)
    except (sqlite3.Error, StorageError):  # not created completely yet: asked again
        return []
    try:
        return [e.time for e in robot.query(kinds=["blackbox_event"])
                if e.payload.get("event") == "start"][:1]
    finally:
        robot.close()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    tmp = tmp_path_factory.mktemp("station")
    domain = fresh_domain()
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    db = tmp / "station.db"
    for name, password in PASSWORDS.items():
        added = subprocess.run([*BLACKBOX, "station", "user", "add", name, "--role",
                                ROLES[name], "--db", str(db)], input=password + "\n",
                               capture_output=True, text=True, timeout=60, env=env)
        assert added.returncode == 0, added.stderr
    faults = tmp / "faults.yaml"
    faults.write_text("faults:\n  - {kind: kill, component: /usb_cam, "
                      f"start: {FAULT_START}, end: {FAULT_END}}}\n")
    record = tmp / "robot.db"
    started = time.time()
    key, config = station_trusted_by(ROOT / "src/blackbox/configs/thesis.yaml", tmp,
                                     "browser-station")
    box = subprocess.Popen([*BLACKBOX, "run", "--dds", "--domain", str(domain), "--quiet",
                            "--config", str(config),
                            "--faults", str(faults), "--record", str(record),
                            "--duration", str(RUN_FOR)], env=env,
                           stdout=(tmp / "box.log").open("wb"), stderr=subprocess.STDOUT)
    ready = tmp / "ready"
    station = subprocess.Popen([*BLACKBOX, "station", "--db", str(db), "--key", str(key),
                                "--bind",
                                "127.0.0.1:0", "--domain", str(domain), "--ready-file",
                                str(ready), "--duration", str(RUN_FOR + 30),
                                "--login-backoff", str(LOGIN_BACKOFF)], env=env,
                               stdout=(tmp / "station.log").open("wb"),
                               stderr=subprocess.STDOUT)
    try:
        assert wait_for(lambda: ready.exists() and ready.read_text().endswith("\n"), 60), \
            (tmp / "station.log").read_text()
        # The fault schedule counts from the robot's own start, which a loaded machine
        # delays by seconds after the process was spawned: read it from its record.
        robot_start: list[float] = []
        assert wait_for(lambda: bool(robot_start.extend(_started(record)) or robot_start),
                        60), "the robot's record has its start event within 60 s"
        yield Fleet(ready.read_text().strip().rstrip("/"), record,
                    max(started, robot_start[0]), tmp)
    finally:
        _stop(station)
        _stop(box)


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    with playwright_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=str(CHROMIUM))
        yield chromium
        chromium.close()


SCRIPT_ERRORS: list[str] = []


@pytest.fixture(autouse=True)
def no_script_errors() -> Iterator[None]:
    """Every page of every test runs its JavaScript without an error (CSP included)."""
    SCRIPT_ERRORS.clear()
    yield
    assert SCRIPT_ERRORS == []


def new_page(browser: object, fleet: Fleet, user: str | None = None) -> object:
    context = browser.new_context(viewport={"width": 1280, "height": 860},  # type: ignore
                                  base_url=fleet.url, accept_downloads=True)
    page = context.new_page()
    page.on("pageerror", lambda error: SCRIPT_ERRORS.append(str(error)))
    page.on("console", lambda m: SCRIPT_ERRORS.append(m.text) if m.type == "error" and not
            m.text.startswith("Failed to load resource") else None)  # refusals are tested
    page.set_default_timeout(20_000)
    if user is not None:
        log_in(page, user, PASSWORDS[user])
        assert page.url.endswith("/"), page.url
    return page


def log_in(page: object, user: str, password: str, *, here: bool = False) -> None:
    if not here:
        page.goto("/login")  # type: ignore[attr-defined]
    page.fill("input[name=username]", user)  # type: ignore[attr-defined]
    page.fill("input[name=password]", password)  # type: ignore[attr-defined]
    with page.expect_navigation():  # type: ignore[attr-defined]
        page.click("button[type=submit]")  # type: ignore[attr-defined]


def utc_input(t: float) -> str:
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%S")


# First in the module: it must see the kill of /usb_cam (FAULT_START to FAULT_END after the
# robot's start), so it runs before the tests whose page loads take a loaded machine long.
def test_a_killed_node_turns_red_without_reload_and_green_after_recovery(
        browser: object, fleet: Fleet) -> None:
    page = new_page(browser, fleet, "otto")
    page.goto("/robot?r=thesis-robot&zoom=5m")
    page.locator("body[data-live=open]").wait_for()
    page.evaluate("window.__sameDocument = true")
    usb_cam = page.locator("li.entity[data-name='/usb_cam']")
    if time.time() < fleet.started + FAULT_START - 1:  # green before the kill
        usb_cam.and_(page.locator(".h-operational")).wait_for(timeout=20_000)
    # red while killed (FAULT_START to FAULT_END, then a few seconds to clear)
    assert time.time() < fleet.started + FAULT_END, \
        "this test began after the kill was over: the tests before it took too long"
    usb_cam.and_(page.locator(".h-not-operational")).wait_for(
        timeout=(fleet.started + FAULT_START - time.time() + 25) * 1000)
    headline = page.locator("#headlines .hl-text", has_text="/usb_cam is not")
    headline.wait_for()  # the headline first, live: what, since when, how sure
    words = headline.inner_text()
    assert " — since " in words and ("explanation" in words or "unique" in words), words
    assert page.locator("#diagnosis-components").text_content() == "/usb_cam"

    def one_status() -> bool:
        """Badge, the tree's robot row and the robot's own UCMS report say the same."""
        badge = page.locator("#robot-status").inner_text()
        tree = page.locator("li.entity.kind-robot [data-field=status]").inner_text()
        db = sqlite3.connect(f"file:{fleet.tmp / 'station.db'}?mode=ro", uri=True)
        try:
            reported = db.execute("SELECT status FROM entities WHERE kind = 'robot'"
                                  ).fetchone()
        finally:
            db.close()
        return badge == tree == (reported[0] if reported else "")
    assert wait_for(one_status, 10), "badge, tree and UCMS report disagree for 10 s"
    failure = page.locator("table.events tr.ev-failure").first  # the timeline is live too
    failure.wait_for()
    assert "/usb_cam" in failure.inner_text()
    assert page.evaluate("window.__sameDocument") is True  # updated in place
    page.locator("#timeline g.lane[data-entity='/usb_cam'] rect.span[fill='#cf222e']"
                 ).wait_for()  # the timeline is redrawn live, red from the failure on
    fleet.shot(page, "robot", full_page=True)
    page.set_viewport_size({"width": 768, "height": 1024})  # a tablet in the control room
    fleet.shot(page, "robot-768", full_page=True)
    page.set_viewport_size({"width": 1280, "height": 860})
    fleet_page = new_page(browser, fleet, "otto")
    fleet_page.locator("body[data-live=open]").wait_for()
    row = fleet_page.locator("tr[data-robot='thesis-robot']")
    row.locator("[data-field=diagnosis]", has_text="/usb_cam").wait_for()
    fleet.shot(fleet_page, "fleet")
    fleet_page.context.close()

    usb_cam.and_(page.locator(".h-operational")).wait_for(
        timeout=(fleet.started + FAULT_END - time.time() + 25) * 1000)
    assert page.evaluate("window.__sameDocument") is True
    page.context.close()


def test_unauthenticated_pages_redirect_to_log_in(browser: object, fleet: Fleet) -> None:
    page = new_page(browser, fleet)
    page.goto("/robot?r=thesis-robot")
    assert "/login?next=" in page.url
    assert page.locator("h1").inner_text() == "Log in"
    fleet.shot(page, "login")
    log_in(page, "vera", PASSWORDS["vera"], here=True)  # then back where it was going
    assert page.url.endswith("/robot?r=thesis-robot")
    page.context.close()


def test_wrong_password_is_refused_and_repeated_ones_are_throttled(
        browser: object, fleet: Fleet) -> None:
    page = new_page(browser, fleet)
    log_in(page, "tess", "not my password")
    assert page.locator("#login-message").inner_text() == "Wrong user name or password."
    for _ in range(3):
        log_in(page, "tess", "not my password")
    assert "Too many failed log-ins" in page.locator("#login-message").inner_text()
    log_in(page, "tess", PASSWORDS["tess"])  # the right one must wait too
    assert "Too many failed log-ins" in page.locator("#login-message").inner_text()
    log_in(page, "vera", PASSWORDS["vera"])  # other users are not locked out
    assert page.locator("h1").inner_text() == "Fleet"
    page.context.close()


def test_a_viewer_gets_403_on_log_requests_and_ibit(browser: object, fleet: Fleet) -> None:
    page = new_page(browser, fleet, "vera")
    csrf = page.locator("body").get_attribute("data-csrf")
    for path in ("/logs", "/ibit"):
        reply = page.request.post(path, form={"csrf_token": csrf, "robot": "thesis-robot"})
        assert reply.status == 403, path
    page.goto("/robot?r=thesis-robot")
    assert page.locator("#ibit-robot").count() == 0  # no button either
    page.context.close()


def test_posts_without_csrf_token_are_refused(browser: object, fleet: Fleet) -> None:
    page = new_page(browser, fleet, "ada")
    for path in ("/logs", "/ibit", "/users", "/logout"):
        reply = page.request.post(path, form={"robot": "thesis-robot", "op": "add",
                                              "name": "mallory", "role": "admin",
                                              "password": "mallory password"})
        assert reply.status == 403, path
    page.goto("/users")
    assert "mallory" not in page.locator("table.users").inner_text()
    page.context.close()


def test_a_log_downloaded_from_the_page_equals_the_robots_own_health_log(
        browser: object, fleet: Fleet) -> None:
    from blackbox.record import Store

    page = new_page(browser, fleet, "otto")
    since = int(fleet.started) + 2

    def logged(until: int) -> int:
        robot = Store.open(fleet.record, readonly=True, check=False)
        try:
            return sum(1 for _ in robot.query(start=since, end=until))
        finally:
            robot.close()
    # A window that holds some history (this test may run first in its module).
    deadline = time.monotonic() + 60
    while logged(int(time.time()) - 3) <= 10 and time.monotonic() < deadline:
        time.sleep(0.5)
    until = int(time.time()) - 3
    page.goto("/logs?robot=thesis-robot")
    page.fill("input[name=since]", utc_input(since))
    page.fill("input[name=until]", utc_input(until))
    page.click("#log-form button[type=submit]")
    page.locator("#log-downloads:not(.hidden)").wait_for(timeout=60_000)
    assert page.locator("#log-status").inner_text() == "done"
    fleet.shot(page, "logs")
    with page.expect_download() as download:
        page.click("#dl-jsonl")
    downloaded = [json.loads(line) for line in
                  Path(download.value.path()).read_text().splitlines() if line.strip()]

    robot = Store.open(fleet.record, readonly=True, check=False)
    try:
        expected = [json.loads(json.dumps(e.to_dict()))
                    for e in robot.query(start=since, end=until)]
    finally:
        robot.close()
    assert len(expected) > 10
    assert downloaded == expected
    with page.expect_download() as download:
        page.click("#dl-csv")
    rows = list(csv.reader(Path(download.value.path()).read_text().splitlines()))
    assert rows[0][:3] == ["id", "time", "kind"]
    assert [int(r[0]) for r in rows[1:]] == [e["id"] for e in expected]
    with page.expect_download() as download:
        page.click("#dl-mcap")
    assert Path(download.value.path()).read_bytes()[:5] == b"\x89MCAP"
    page.context.close()


def test_entity_ibit_and_events_pages(browser: object, fleet: Fleet) -> None:
    page = new_page(browser, fleet, "otto")
    page.goto("/robot?r=thesis-robot")
    with page.expect_navigation():
        page.click("li.entity[data-name='/usb_cam/image_raw'] a.name")
    page.locator("body[data-live=open]").wait_for()
    assert page.locator("h1").inner_text().startswith("/usb_cam/image_raw")
    page.locator("figure.chart .uplot").first.wait_for()
    page.wait_for_timeout(1500)  # a few live points
    fleet.shot(page, "entity", full_page=True)
    page.click("#ibit-entity")  # an operator runs the built-in test of this entity
    page.locator("#ibit-status", has_text="done").wait_for(timeout=30_000)
    assert page.locator("#ibit-report li").count() >= 1
    assert "/usb_cam/image_raw" in page.locator("#ibit-report").inner_text()
    fleet.shot(page, "ibit")
    # The camera's failure reaches the station's database a moment after its state (its
    # identity and signature travel on their own topics): look again until it is there.
    deadline = time.monotonic() + 30
    while True:
        page.goto("/events?robot=thesis-robot&kind=failure")
        shown = page.locator("table.events").inner_text()
        if "/usb_cam" in shown or time.monotonic() > deadline:
            break
        page.wait_for_timeout(500)
    assert "/usb_cam" in shown, f"waited 30 s for the camera's failure on the events page: {shown}"
    fleet.shot(page, "events")
    page.set_viewport_size({"width": 768, "height": 1024})
    fleet.shot(page, "events-768")
    page.context.close()
