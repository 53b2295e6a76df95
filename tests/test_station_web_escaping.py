"""Names from robots are text in the browser too: a node called ``<script>alert(1)</script>``
(and an event text and a diagnosis naming it) is shown as those characters, on the first
render and after live updates, and no script of theirs ever runs.

Debian's Chromium (Playwright) against the real web application served by uvicorn in a
thread, on a real station database filled through the store's write API.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.health.ids import robot_resource_id
from blackbox.station.auth import Role
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from station_support import Unreachable, quick_auth

CHROMIUM = Path("/usr/bin/chromium")
playwright_api = pytest.importorskip("playwright.sync_api")
uvicorn = pytest.importorskip("uvicorn")
pytestmark = pytest.mark.skipif(not CHROMIUM.exists(),
                                reason="needs Debian's chromium (scripts/install-system-deps.sh)")

EVIL = "<script>alert(1)</script>"
IMG_EVIL = '<img src=x onerror="alert(2)">'
PASSWORD = "station password 1"


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[str, StationStore]]:
    path = tmp_path / "station.db"
    store = StationStore.open(path, stale_after=3600.0)  # the robot stays heard throughout
    auth = quick_auth(path)
    auth.add_user("vera", PASSWORD, Role.OPERATOR)
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
    assert server.started
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}", store
    finally:
        stop.set()  # ends the live streams first, else uvicorn waits for them
        server.should_exit = True
        thread.join(timeout=15)
        auth.close()
        store.close()


def test_robot_supplied_markup_is_shown_as_text_and_never_runs(
        served: tuple[str, StationStore]) -> None:
    url, store = served
    rid = robot_resource_id("evil-bot")
    store.heard(rid, time.time())
    store.put_robot_id(rid, "evil-bot")
    store.put_entity(rid, 1, name="evil-bot", kind="robot", status="DEGRADED")
    store.put_entity(rid, 2, name=EVIL, kind="node", parent=1, status="OPERATIONAL")
    store.put_characteristic(rid, 10, entity=2, name=IMG_EVIL, unit="<b>Hz</b>")
    store.put_value(rid, 10, time.time(), 1.0)
    assert store.flush(force=True)

    dialogs: list[str] = []
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM))
        page = browser.new_page(base_url=url)
        page.on("dialog", lambda d: (dialogs.append(d.message), d.dismiss()))
        page.set_default_timeout(15_000)
        page.goto("/login")
        page.fill("input[name=username]", "vera")
        page.fill("input[name=password]", PASSWORD)
        with page.expect_navigation():
            page.click("button[type=submit]")
        page.goto("/robot?r=evil-bot")
        page.locator("body[data-live=open]").wait_for()
        assert page.locator("li.entity[data-entity='2'] a.name").inner_text() == EVIL

        # live: the node fails, a diagnosis and an event name it; all arrive as text
        now = time.time()
        store.put_entity(rid, 2, status="NOT_OPERATIONAL", cause=IMG_EVIL)
        store.put_diagnosis(rid, [EVIL], now)
        store.add_event(rid, now, "failure", dedup="evil", entity=EVIL, text=f"{IMG_EVIL} died")
        assert store.flush(force=True)
        page.locator("li.entity.h-not-operational[data-entity='2']").wait_for()
        page.locator("table.events tr.ev-failure").first.wait_for()
        assert page.locator("#headlines .hl-text b").first.inner_text() == \
            f"{EVIL} is not working"
        assert page.locator("#diagnosis-components").text_content() == EVIL  # one click away
        assert IMG_EVIL in (page.locator("#diagnosis-explanation").text_content() or "")
        assert f"{IMG_EVIL} died" in (page.locator("table.events").text_content() or "")
        assert f"{EVIL} is not working" in page.locator("table.events").inner_text()
        assert page.locator("main script, main img").count() == 0

        with page.expect_navigation():
            page.click("li.entity[data-entity='2'] a.name")
        assert page.locator("h1").inner_text().startswith(EVIL)
        assert IMG_EVIL in page.locator("table.chars").inner_text()
        assert page.locator("main img").count() == 0
        browser.close()
    assert dialogs == []
