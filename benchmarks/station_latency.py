"""Station latency benchmark: a fault on the robot -> the colour change in the browser.

Runs the real chain: ``blackbox run --dds`` on the simulated thesis robot with a fault
schedule that kills ``/usb_cam`` again and again, ``blackbox station`` following it over
Cyclone DDS (loopback), and Debian's Chromium (Playwright) showing the robot page. A
MutationObserver in the page stamps (``Date.now()``) every colour change of the
``/usb_cam`` entity; all processes read the same clock.

Reported, p50/p99/max over every transition:

* **fault -> red**: injection of the kill (the simulator's ground truth) to the entity
  turning red in the browser: detection + diagnosis + DDS + station + SSE + paint;
* **detected -> red** / **rectified -> green**: the black box's own record of the
  failure / rectification (its health log) to the colour change;
* **detected -> DDS**: the black box's record to its UCMS ``C_Monitored_Entity`` sample
  with the new status arriving at a DDS reader in this process (the black box's share);
* **DDS -> SSE**: that sample to the station's Server-Sent Events stream, read by a second
  client in this process, sending the new status (the station's share);
* **SSE -> red**: the stream's message to the browser painting it.

    .venv/bin/python benchmarks/station_latency.py --seconds 120
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from support import BLACKBOX, stop

CHROMIUM = "/usr/bin/chromium"
ENTITY = "/usb_cam"
OBSERVE = """
window.__changes = [];
const li = document.querySelector("li.entity[data-name='ENTITY']");
new MutationObserver(() => {
  const c = ["h-operational", "h-degraded", "h-not-operational", "h-unknown"]
    .find((k) => li.classList.contains(k));
  const last = window.__changes[window.__changes.length - 1];
  if (!last || last[1] !== c) window.__changes.push([Date.now() / 1000, c]);
}).observe(li, {attributes: true, attributeFilter: ["class"]});
""".replace("ENTITY", ENTITY)


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))]


def summary(name: str, values: list[float]) -> str:
    if not values:
        return f"{name:<22} no samples"
    ms = [v * 1000 for v in values]
    return (f"{name:<22} n={len(ms):3d}  p50 {percentile(ms, 0.5):7.0f} ms  "
            f"p99 {percentile(ms, 0.99):7.0f} ms  max {max(ms):7.0f} ms  "
            f"mean {statistics.fmean(ms):7.0f} ms")


def first_after(times: list[float], t: float, limit: float = 30.0) -> float | None:
    later = [x for x in times if t <= x <= t + limit]
    return min(later) if later else None


def follow_stream(url: str, entity_id: str, out: list[tuple[float, str]],
                  stop: threading.Event) -> None:
    """Log in as a second client and stamp every status of the entity the stream sends."""
    import re

    import httpx

    with httpx.Client(base_url=url, timeout=10) as client:
        form = client.get("/login").text
        token = re.search(r'name="login_token" value="([^"]+)"', form)
        assert token
        client.post("/login", data={"username": "bench", "password": "benchmark password",
                                    "login_token": token.group(1)})
        last = None
        with client.stream("GET", "/api/stream?view=robot&r=thesis-robot",
                           timeout=None) as reply:
            for line in reply.iter_lines():
                if stop.is_set():
                    return
                if line.startswith("data:"):
                    status = json.loads(line[5:]).get("entities", {}).get(entity_id)
                    if status and status != last:
                        out.append((time.time(), status))
                        last = status


def follow_dds(domain: int, instance: int, out: list[tuple[float, int]],
               stop: threading.Event) -> None:
    """Stamp every health status of one entity as its UCMS samples arrive over DDS."""
    from blackbox.health.types import C_Monitored_Entity
    from blackbox.transport.participant import Bus, TransportSettings

    bus = Bus.open(TransportSettings(domain))
    reader = bus.reader("C_Monitored_Entity")
    last = None
    try:
        while not stop.is_set():
            for sample in reader.take(N=64):
                if (isinstance(sample, C_Monitored_Entity)
                        and sample.A_sourceID.A_instanceId == instance):
                    status = int(sample.A_healthStatus.value)
                    if status != last:
                        out.append((time.time(), status))
                        last = status
            time.sleep(0.005)
    finally:
        bus.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--period", type=float, default=14.0,
                        help="seconds between kills (each lasts 5 s)")
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from blackbox.cli.station import open_databases
    from blackbox.record import Store
    from blackbox.station.auth import Role

    tmp = Path(tempfile.mkdtemp(prefix="station-latency-"))
    domain = 120 + os.getpid() % 30
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    kills = []
    t = 20.0  # after the station, the browser and the page's observer are up
    while t + 8 < args.seconds:
        kills.append((t, t + 5.0))
        t += args.period
    (tmp / "faults.yaml").write_text("faults:\n" + "".join(
        f"  - {{kind: kill, component: {ENTITY}, start: {a}, end: {b}}}\n" for a, b in kills))
    store, auth = open_databases(tmp / "station.db")
    auth.add_user("bench", "benchmark password", Role.VIEWER)
    auth.close()
    store.close()
    box = subprocess.Popen([*BLACKBOX, "run", "--dds", "--domain", str(domain), "--quiet",
                            "--faults", str(tmp / "faults.yaml"), "--record",
                            str(tmp / "robot.db"), "--ground-truth", str(tmp / "truth.jsonl"),
                            "--duration", str(args.seconds)], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    station = subprocess.Popen([*BLACKBOX, "station", "--db", str(tmp / "station.db"),
                                "--bind", "127.0.0.1:0", "--domain", str(domain),
                                "--ready-file", str(tmp / "url")], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    changes: list[list[object]] = []
    streamed: list[tuple[float, str]] = []
    sampled: list[tuple[float, int]] = []
    stop_stream = threading.Event()
    observing = float("inf")
    try:
        deadline = time.monotonic() + 60
        while not (tmp / "url").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        url = (tmp / "url").read_text().strip()
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM)
            page = browser.new_page(base_url=url)
            page.goto("/login")
            page.fill("input[name=username]", "bench")
            page.fill("input[name=password]", "benchmark password")
            page.click("button[type=submit]")
            page.wait_for_load_state()
            page.goto("/robot?r=thesis-robot")
            while page.locator(f"li.entity[data-name='{ENTITY}']").count() == 0:
                if time.monotonic() > deadline:
                    raise SystemExit("the robot page never listed the entity")
                page.wait_for_timeout(500)
                page.goto("/robot?r=thesis-robot")
            page.locator("body[data-live=open]").wait_for()
            entity_id = page.locator(f"li.entity[data-name='{ENTITY}']").get_attribute(
                "data-entity")
            assert entity_id
            for target, arguments in ((follow_stream, (url, entity_id, streamed, stop_stream)),
                                      (follow_dds, (domain, int(entity_id), sampled,
                                                    stop_stream))):
                threading.Thread(target=target, args=arguments, daemon=True).start()
            page.evaluate(OBSERVE)
            observing = time.time()
            box.wait(timeout=args.seconds + 60)
            page.wait_for_timeout(2000)
            changes = page.evaluate("window.__changes")
            browser.close()
    finally:
        stop_stream.set()
        for proc in (station, box):
            stop(proc, timeout=15)

    red = [float(t) for t, c in changes if c == "h-not-operational"]
    green = [float(t) for t, c in changes if c == "h-operational"]
    truth = [json.loads(line) for line in (tmp / "truth.jsonl").read_text().splitlines()
             if line.strip()]
    injected = [float(f["start"]) for f in truth
                if f["component"] == ENTITY and float(f["start"]) > observing]
    robot = Store.open(tmp / "robot.db", readonly=True, check=False)
    detected, rectified = [], []
    for entry in robot.query(kinds=["failure"]):
        if ENTITY not in entry.payload.get("components", []):
            continue
        if entry.time > observing:
            (rectified if entry.payload.get("category") == "rectification"
             else detected).append(entry.time)
    robot.close()

    def lat(starts: list[float], ends: list[float], limit: float = 30.0) -> list[float]:
        out = []
        for s in starts:
            e = first_after(ends, s, limit)
            if e is not None:
                out.append(e - s)
        return out

    print(f"station latency: {len(kills)} kills of {ENTITY} over {args.seconds:.0f} s; "
          f"{len(red)} red and {len(green)} green changes seen in the browser; "
          f"{len(detected)} detections, {len(rectified)} rectifications in the robot's log")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}")
    print(summary("fault -> red", lat(injected, red)))
    print(summary("detected -> red", lat(detected, red)))
    print(summary("rectified -> green", lat(rectified, green)))
    sse_red = [t for t, c in streamed if c == "NOT_OPERATIONAL" and t > observing]
    sse_green = [t for t, c in streamed if c == "OPERATIONAL" and t > observing]
    dds_red = [t for t, c in sampled if c == 2 and t > observing]
    print(summary("detected -> DDS red", lat(detected, dds_red, 5.0)))
    print(summary("DDS red -> SSE red", lat(dds_red, sse_red, 5.0)))
    print(summary("SSE red -> red", lat(sse_red, red, 5.0)))
    print(summary("SSE green -> green", lat(sse_green, green, 5.0)))
    missed = len(injected) - len(lat(injected, red))
    if missed:
        print(f"{missed} injected kill(s) never turned the entity red within 30 s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
