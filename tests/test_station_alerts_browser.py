"""The alerts page in a real browser (Debian's Chromium driven by Playwright) against the
real station application served by uvicorn on 127.0.0.1, with the alert service running and
real webhook receivers: an admin adds a rule and sends a test notification, an alert
escalates and the page shows it, an operator acknowledges, unmatched events are shown.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from alert_support import Receiver, robot_with_entity, rules_file, webhook_receiver
from blackbox.station.alerts.rules import load_alert_config
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Role
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from conftest import wait_for
from station_support import Unreachable, quick_auth

CHROMIUM = Path("/usr/bin/chromium")
playwright_api = pytest.importorskip("playwright.sync_api")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium"),
              pytest.mark.xdist_group("test_station_alerts_browser")]  # one Chromium
PASSWORD = "station password 1"


@dataclass
class Site:
    url: str
    store: StationStore
    rid: int
    alerts: AlertService
    hook: Receiver
    pager: Receiver
    auth: Any


@pytest.fixture
def site(tmp_path: Path) -> Iterator[Site]:
    import uvicorn

    path = tmp_path / "station.db"
    store = StationStore.open(path)
    auth = quick_auth(path)
    auth.add_user("ada", PASSWORD, Role.ADMIN)
    auth.add_user("otto", PASSWORD, Role.OPERATOR)
    rid = robot_with_entity(store)
    with webhook_receiver() as hook, webhook_receiver() as pager:
        config = load_alert_config(rules_file(tmp_path, f"""\
delivery: {{attempts: 3, backoff: 0.1}}
channels:
  hook: {{type: webhook, url: "{hook.url}", secret: "0123456789abcdef"}}
  pager: {{type: webhook, url: "{pager.url}", secret: "0123456789abcdef"}}
rules:
  - name: cameras
    match: {{entity: /usb_cam, kind: failure}}
    send: hook
    escalate: [{{after: 1, send: pager}}]
  - name: lidar
    match: {{entity: /lidar, kind: failure}}
    send: hook
    escalate: [{{after: 600, send: pager}}]
"""))
        alerts = AlertService(store, path, config, tick=0.1,
                              audit=lambda u, a, t, o, d: auth.audit(u, a, t, o, "station", d))
        alerts.start()
        app = create_app(auth, store, Unreachable(), alerts=alerts)
        sock = socket.socket()
        sock.bind(("127.0.0.1", 0))
        sock.listen(64)
        server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False))
        thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
        thread.start()
        assert wait_for(lambda: server.started or not thread.is_alive(), 20)
        assert server.started, "waited for uvicorn to start"
        try:
            yield Site(f"http://127.0.0.1:{sock.getsockname()[1]}", store, rid, alerts,
                       hook, pager, auth)
        finally:
            server.should_exit = True
            thread.join(timeout=15)
            alerts.stop()
            auth.close()
            store.close()


@pytest.fixture(scope="module")
def chromium() -> Iterator[Any]:
    """One Chromium for the module (Playwright's driver and the browser cost about 2 s of
    CPU to start); each test's pages get contexts of their own."""
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


SCRIPT_ERRORS: list[str] = []


@pytest.fixture(autouse=True)
def no_script_errors() -> Iterator[None]:
    """Any script error or CSP violation on a page fails the test."""
    SCRIPT_ERRORS.clear()
    yield
    assert SCRIPT_ERRORS == []


def logged_in(browser: Any, site: Site, user: str) -> Any:
    page = browser.new_context(base_url=site.url).new_page()
    page.on("pageerror", lambda error: SCRIPT_ERRORS.append(str(error)))
    page.on("console", lambda m: SCRIPT_ERRORS.append(m.text) if m.type == "error" and not
            m.text.startswith("Failed to load resource") else None)  # refusals are tested
    page.set_default_timeout(20_000)
    page.goto("/login")
    page.fill("input[name=username]", user)
    page.fill("input[name=password]", PASSWORD)
    with page.expect_navigation():
        page.click("button[type=submit]")
    return page


def fail(site: Site, entity: str, n: int) -> None:
    site.store.add_event(site.rid, time.time(), "failure", dedup=f"f{n}", entity=entity,
                         text=f"{entity} stopped publishing")
    assert site.store.flush(force=True)


def reload_until(page: Any, selector: str, text: str, timeout: float = 20) -> None:
    def shown() -> bool:
        page.reload()
        return text in page.locator(selector).inner_text()
    assert wait_for(shown, timeout, step=0.3), f"waited for {text!r} in {selector}"


def test_an_admin_adds_a_rule_and_sends_a_test_notification(browser: Any, site: Site) -> None:
    page = logged_in(browser, site, "ada")
    with page.expect_navigation():
        page.click("text=Alerts")
    assert page.locator("h1").inner_text() == "Alerts"
    page.fill("#add-rule textarea", "name: robots gone quiet\nsend: nope\n")
    with page.expect_navigation():
        page.click("#add-rule button")
    assert "at send: unknown channel 'nope'" in page.locator("#alerts-message").inner_text()
    page.fill("#add-rule textarea", "name: robots gone quiet\nsend: [hook]\n"
                                    "match: {kind: robot_silent}\n")
    with page.expect_navigation():
        page.click("#add-rule button")
    row = page.locator("tr[data-rule='robots gone quiet']")
    assert "page" in row.inner_text()
    with page.expect_navigation():
        page.locator("tr[data-rule='cameras'] >> text=Send a test notification").click()
    assert "Test notification queued" in page.locator("#alerts-message").inner_text()
    # (on a loaded machine a robot may go quiet meanwhile: its alert can come first)
    got = site.hook.wait_for_one(lambda r: r.json.get("type") == "test",
                                 "test notification", timeout=15).json
    assert (got["type"], got["rule"]) == ("test", "cameras")
    assert "sent by ada" in got["summary"]


def test_the_page_shows_escalation_acknowledgement_and_unmatched_events(
        browser: Any, site: Site) -> None:
    fail(site, "/usb_cam", 1)
    escalated = site.pager.wait_for(1, timeout=20)[0].json
    assert (escalated["type"], escalated["alert"]["entity"]) == ("escalation", "/usb_cam")
    fail(site, "/lidar", 2)
    fail(site, "/imu", 3)  # no rule for it
    page = logged_in(browser, site, "otto")
    page.goto("/alerts")
    camera = page.locator("#alerts tr", has_text="/usb_cam")
    reload_until(page, "#alerts", "/lidar")
    assert camera.locator("td").nth(8).inner_text() == "1"  # one escalation step taken
    lidar = page.locator("#alerts tr", has_text="/lidar")
    assert "firing" in lidar.inner_text()
    with page.expect_navigation():
        lidar.locator("text=Acknowledge").click()
    lidar = page.locator("#alerts tr", has_text="/lidar")
    assert "acknowledged by otto" in lidar.locator(".alert-state").inner_text()
    reload_until(page, "#unmatched", "1 failure event in the last hour matched no alert rule")
    audit = [(a.user, a.action, a.outcome) for a in site.auth.audit_log(limit=50)]
    assert ("otto", "alert.ack", "ok") in audit
    assert ("station", "alert.escalate", "ok") in audit
