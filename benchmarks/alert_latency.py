"""Alert latency benchmark: a fault on the robot -> the webhook at the on-call receiver.

Runs the real chain: ``blackbox run --dds`` on the simulated thesis robot with a fault
schedule that kills ``/usb_cam`` again and again, ``blackbox station --alerts`` following it
over Cyclone DDS (loopback) with one rule sending to a webhook, and a webhook receiver in
this process (HTTP on 127.0.0.1) that stamps every request it accepts. All processes read
the same clock.

Reported, p50/p99/max over every kill (goal of issue 26: fault -> webhook p99 <= 2 s is
about the station's share; detection itself needs the observers' windows):

* **fault -> webhook**: injection of the kill (the simulator's ground truth) to the alert
  arriving at the receiver: detection + diagnosis + DDS + station + alert engine + HTTP;
* **detected -> webhook**: the black box's own record of the failure (its health log) to
  the alert arriving: DDS + station store + alert engine + outbox + HTTP;
* **rectified -> resolved**: the record of the rectification to the ``resolved`` message;
* **detected -> alert opened** (DDS + follower + store + engine) and **opened -> webhook**
  (outbox + delivery thread + HTTP), from the alert's ``first`` time in the body.

    .venv/bin/python benchmarks/alert_latency.py --seconds 120
"""

from __future__ import annotations

import argparse
import http.server
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from station_latency import first_after, summary
from support import BLACKBOX, stop

ENTITY = "/usb_cam"
SECRET = "alert latency benchmark secret"


def receiver(out: list[tuple[float, dict[str, Any]]]) -> http.server.ThreadingHTTPServer:
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
            at = time.time()
            self.send_response(204)
            self.end_headers()
            out.append((at, json.loads(body)))

        def log_message(self, format: str, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--period", type=float, default=14.0,
                        help="seconds between kills (each lasts 5 s)")
    args = parser.parse_args()

    from blackbox.cli.station import open_databases
    from blackbox.record import Store

    tmp = Path(tempfile.mkdtemp(prefix="alert-latency-"))
    domain = 150 + os.getpid() % 30
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    kills = []
    t = 15.0
    while t + 8 < args.seconds:
        kills.append((t, t + 5.0))
        t += args.period
    (tmp / "faults.yaml").write_text("faults:\n" + "".join(
        f"  - {{kind: kill, component: {ENTITY}, start: {a}, end: {b}}}\n" for a, b in kills))
    got: list[tuple[float, dict[str, Any]]] = []
    server = receiver(got)
    (tmp / "alerts.yaml").write_text(f"""\
channels:
  oncall: {{type: webhook, url: "http://127.0.0.1:{server.server_address[1]}/hook",
            secret: "{SECRET}"}}
rules:
  - name: camera
    match: {{entity: "{ENTITY}", kind: failure}}
    send: oncall
    rate_limit: {{count: 1000, per: 60}}
""")
    store, auth = open_databases(tmp / "station.db")
    auth.close()
    store.close()
    station = subprocess.Popen([*BLACKBOX, "station", "--db", str(tmp / "station.db"),
                                "--bind", "127.0.0.1:0", "--domain", str(domain),
                                "--alerts", str(tmp / "alerts.yaml"),
                                "--ready-file", str(tmp / "url")], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not (tmp / "url").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    started = time.time()
    box = subprocess.Popen([*BLACKBOX, "run", "--dds", "--domain", str(domain), "--quiet",
                            "--faults", str(tmp / "faults.yaml"), "--record",
                            str(tmp / "robot.db"), "--ground-truth", str(tmp / "truth.jsonl"),
                            "--duration", str(args.seconds)], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        box.wait(timeout=args.seconds + 60)
        time.sleep(2.0)  # the last messages in flight
    finally:
        for proc in (box, station):
            stop(proc, timeout=15)
        server.shutdown()

    alerts = [t for t, body in got if body.get("type") == "alert"]
    resolved = [t for t, body in got if body.get("type") == "resolved"]
    truth = [json.loads(line) for line in (tmp / "truth.jsonl").read_text().splitlines()
             if line.strip()]
    injected = [float(f["start"]) for f in truth
                if f["component"] == ENTITY and float(f["start"]) > started]
    robot = Store.open(tmp / "robot.db", readonly=True, check=False)
    detected, rectified = [], []
    for entry in robot.query(kinds=["failure"]):
        if ENTITY in entry.payload.get("components", []):
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

    print(f"alert latency: {len(kills)} kills of {ENTITY} over {args.seconds:.0f} s; "
          f"{len(alerts)} alert and {len(resolved)} resolved webhooks received; "
          f"{len(detected)} detections, {len(rectified)} rectifications in the robot's log")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}")
    print(summary("fault -> webhook", lat(injected, alerts)))
    print(summary("detected -> webhook", lat(detected, alerts, 10.0)))
    print(summary("rectified -> resolved", lat(rectified, resolved, 10.0)))
    opened = [float(body["alert"]["first"]) for _, body in got if body.get("type") == "alert"]
    print(summary("of which: detected -> alert opened", lat(detected, opened, 10.0)))
    print(summary("of which: opened -> webhook", [t - float(body["alert"]["first"])
                                                  for t, body in got
                                                  if body.get("type") == "alert"]))
    missed = len(injected) - len(lat(injected, alerts))
    if missed:
        print(f"{missed} injected kill(s) never reached the webhook within 30 s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
