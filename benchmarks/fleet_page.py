"""How fast the fleet page loads with a large fleet: a real station database holding
``--robots`` robots (the thesis robot's shape, 16 % of them faulty or silent, three sites),
the real web application served by uvicorn on 127.0.0.1, timed over real HTTP (the page's
GET as a logged-in viewer) and in Debian's Chromium with Playwright (navigation to the
``load`` event, and until the live stream is open).

    .venv/bin/python benchmarks/fleet_page.py                  # 1,000 robots
    .venv/bin/python benchmarks/fleet_page.py --robots 5000 --repeat 10
"""

from __future__ import annotations

import argparse
import http.client
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import urlencode

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from blackbox.station.alerts.rules import AlertConfig
from blackbox.station.alerts.service import AlertService
from blackbox.station.auth import Role
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from fleet_support import SITES, fill_fleet
from station_support import Unreachable, quick_auth

PASSWORD = "station password 1"
CHROMIUM = "/usr/bin/chromium"


def quantiles(times: list[float]) -> str:
    ordered = sorted(times)
    p95 = ordered[min(len(ordered) - 1, round(0.95 * (len(ordered) - 1)))]
    return (f"median {1000 * statistics.median(ordered):.0f} ms, p95 {1000 * p95:.0f} ms, "
            f"max {1000 * ordered[-1]:.0f} ms (n={len(ordered)})")


def session_cookie(port: int) -> str:
    """Log in over HTTP as the viewer: the log-in form's token, then the session cookie."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    conn.request("GET", "/login")
    r = conn.getresponse()
    body = r.read().decode()
    login_cookie = r.getheader("set-cookie", "").split(";", 1)[0]
    token = body.split('name="login_token" value="', 1)[1].split('"', 1)[0]
    conn.request("POST", "/login", urlencode({"username": "vera", "password": PASSWORD,
                                               "login_token": token, "next": "/"}),
                 {"Content-Type": "application/x-www-form-urlencoded", "Cookie": login_cookie})
    r = conn.getresponse()
    r.read()
    cookies = [c.split(";", 1)[0] for c in (r.headers.get_all("set-cookie") or [])
               if c.startswith("bb_session=")]
    if not cookies:
        raise SystemExit(f"log-in failed: HTTP {r.status}")
    return cookies[0]


def http_times(port: int, cookie: str, path: str, repeat: int) -> list[float]:
    times = []
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    for _ in range(repeat):
        t0 = time.perf_counter()
        conn.request("GET", path, headers={"Cookie": cookie})
        r = conn.getresponse()
        body = r.read()
        times.append(time.perf_counter() - t0)
        if r.status != 200 or b"data-count" not in body:
            raise SystemExit(f"GET {path}: HTTP {r.status}")
    return times


def browser_times(url: str, repeat: int) -> tuple[list[float], list[float]]:
    from playwright.sync_api import sync_playwright

    loads, live = [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM)
        page = browser.new_page(base_url=url, viewport={"width": 1280, "height": 900})
        page.goto("/login")
        page.fill("input[name=username]", "vera")
        page.fill("input[name=password]", PASSWORD)
        page.click("button[type=submit]")
        page.wait_for_load_state()
        for _ in range(repeat):
            t0 = time.perf_counter()
            page.goto("/", wait_until="load")
            loads.append(time.perf_counter() - t0)
            page.locator("body[data-live=open]").wait_for(timeout=15_000)
            live.append(time.perf_counter() - t0)
        browser.close()
    return loads, live


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    import uvicorn

    with tempfile.TemporaryDirectory(prefix="bb-fleet-page-") as tmp:
        path = Path(tmp) / "station.db"
        store = StationStore.open(path, stale_after=600.0)
        auth = quick_auth(path)
        auth.add_user("vera", PASSWORD, Role.VIEWER)
        t0 = time.perf_counter()
        fill_fleet(store, args.robots)
        print(f"station database with {args.robots} robots written in "
              f"{time.perf_counter() - t0:.1f} s ({path.stat().st_size / 1e6:.1f} MB)")
        alerts = AlertService(store, path, AlertConfig(file="alerts.yaml", sites=SITES))
        stop = threading.Event()
        server = uvicorn.Server(uvicorn.Config(
            create_app(auth, store, Unreachable(), stop=stop, alerts=alerts),
            log_level="warning"))
        sock = socket.socket()
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
        thread.start()
        deadline = time.monotonic() + 20
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        try:
            cookie = session_cookie(port)
            print(f"GET / over HTTP:                  "
                  f"{quantiles(http_times(port, cookie, '/', args.repeat))}")
            print(f"GET /?status=DEGRADED&page=1:     "
                  f"{quantiles(http_times(port, cookie, '/?status=DEGRADED&page=1', args.repeat))}")
            print(f"GET /?search=tug-0042:            "
                  f"{quantiles(http_times(port, cookie, '/?search=tug-0042', args.repeat))}")
            loads, live = browser_times(f"http://127.0.0.1:{port}", args.repeat)
            print(f"Chromium: navigation to load:     {quantiles(loads)}")
            print(f"Chromium: until the stream opens: {quantiles(live)}")
        finally:
            stop.set()
            server.should_exit = True
            thread.join(timeout=15)
            auth.close()
            store.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
