"""Station fleet benchmark: N simulated black boxes on one DDS domain feeding one station.

Each simulated black box is a real ``DdsHealthSink`` publishing the thesis robot's health
stream (3 nodes, 10 observers, 11 characteristics at 1 Hz) with a camera fault of
``--fault-length`` s every ``--fault-every`` s (phase shifted per robot), each with a
diagnosis naming ``/usb_cam`` and, when it ends, a rectification. The robots run in
``--processes`` processes; every robot counts what it wrote. One station process follows
them all into its own database:

* ``--station web`` (default when ``blackbox station`` exists): the real ``blackbox station``
  (follower + store + web application), and the fleet page is fetched over HTTP while the
  fleet runs (log-in as a viewer created for the run; plain GET timing);
* ``--station core``: the follower and the store alone (``StationFollower`` +
  ``StationStore``) in a child process.

Reported side by side: station CPU (% of one core) and RSS, DDS samples and stored rows
per second, and per robot what it published against what the station stored
(characteristic values, exceedances, failures, rectifications); "dropped" must be 0.

    .venv/bin/python benchmarks/station_fleet.py                      # 20 robots, 600 s
    .venv/bin/python benchmarks/station_fleet.py --duration 60        # a short run
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve()
FLEET_SIM = HERE.with_name("fleet_sim.py")
DRAIN_TIMEOUT = 180.0
"""Seconds the station may take, after the robots stopped, to store what it was behind."""
HEARD_TIMEOUT = 600.0
"""Seconds the Zenoh fleet may take until the station has heard every robot."""


# ---- simulated black boxes (child) ----------------------------------------------------------


def robots_child(args: argparse.Namespace) -> int:
    from blackbox.health.types import (
        C_Failure_Event,
        C_Monitored_Characteristic,
        C_Threshold_Exceedence_Event,
    )
    from blackbox.model import Code, Diagnosis, Observation, Resource, State
    from blackbox.transport.publisher import DdsHealthSink

    counted = {C_Monitored_Characteristic: "values", C_Threshold_Exceedence_Event: "exceedances",
               C_Failure_Event: "failures"}

    class CountingSink(DdsHealthSink):
        def __init__(self, *a: Any, **kw: Any) -> None:
            self.counts = {"values": 0, "exceedances": 0, "failures": 0, "rectifications": 0}
            super().__init__(*a, **kw)

        def _write(self, samples: Any) -> None:
            for sample in samples:
                before = self.written
                super()._write([sample])
                name = counted.get(type(sample))
                if name and self.written > before:
                    self.counts[name] += 1

    ok = (State(1, "ok"),)
    cam = Resource(topic="/usb_cam/image_raw", publishers=("/usb_cam",))
    audio = Resource(topic="/audio", publishers=("/audio_capture",))
    sig = Resource(topic="/signal", publishers=("/signal_generator",))

    def observations(t: float, faulty: bool) -> list[Observation]:
        camera = (Observation(t, "hz", cam, Code.NO_STATE_FITS, (), {"period": 0.5},
                              "period 0.5 s fits no state") if faulty else
                  Observation(t, "hz", cam, Code.GENERAL_OK, ok, {"period": 0.0667}))
        return [camera,
                Observation(t, "timeout", cam, Code.GENERAL_OK),
                Observation(t, "hz", audio, Code.GENERAL_OK, ok, {"period": 0.0333}),
                Observation(t, "timeout", audio, Code.GENERAL_OK),
                Observation(t, "hz", sig, Code.GENERAL_OK, ok, {"period": 0.0667}),
                Observation(t, "scores", sig, Code.GENERAL_OK, ok, {"score": 15.0}),
                *(Observation(t, "activated", Resource(node=n), Code.GENERAL_OK)
                  for n in ("/usb_cam", "/audio_capture", "/signal_generator")),
                Observation(t, "resources", Resource(node="/usb_cam"), Code.GENERAL_OK, ok,
                            {"cpu": 3.0, "memory": 2.1e7})]

    ids = args.ids.split(",")
    zenoh = None
    if args.zenoh:
        from blackbox.transport.zenoh_bus import ZenohSettings
        zenoh = ZenohSettings((args.zenoh,))
    sinks = [CountingSink(r, domain_id=args.domain, zenoh=zenoh) for r in ids]
    watched = set(args.watch_ids.split(",")) if args.watch_ids else set()
    transitions: dict[str, list[tuple[float, bool]]] = {r: [] for r in ids if r in watched}
    deadline = time.monotonic() + 600
    if zenoh is not None:  # a robot's session opens at once; measure once all reach the router
        while time.monotonic() < deadline and not all(
                list(sink.bus.session.info.routers_zid()) for sink in sinks):
            time.sleep(0.2)
    elif args.matched:  # DDS: measure once the station's readers matched every robot
        while time.monotonic() < deadline and not all(
                sink._writers[C_Failure_Event].get_matched_subscriptions() for sink in sinks):
            time.sleep(0.2)
    print("ready", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    start = time.time()
    faulty = [False] * len(sinks)
    tick = 0
    while not stop.is_set() and time.time() - start < args.duration:
        t = time.time() + args.clock_offset  # the robot's clock, right or (tests) wrong
        for i, sink in enumerate(sinks):
            phase = (t - args.clock_offset - start + args.index * 7 + i * 3) % args.fault_every
            now_faulty = phase < args.fault_length and time.time() - start >= args.fault_start
            obs = observations(t, now_faulty)
            sink.on_observations(t, obs)
            if now_faulty and not faulty[i]:
                sink.on_diagnosis(Diagnosis(t, (frozenset({"/usb_cam"}),), (obs[0],),
                                            "camera publishes too slowly"))
            elif faulty[i] and not now_faulty:
                sink.on_diagnosis(Diagnosis(t, ()))
                sink.counts["rectifications"] += 1
            if now_faulty != faulty[i] and sink.robot_id in transitions:
                transitions[sink.robot_id].append((time.time(), now_faulty))
            faulty[i] = now_faulty
        tick += 1
        stop.wait(max(0.0, start + tick * args.interval - time.time()))
    time.sleep(1.0)  # let the last samples leave before the writers go
    out = {}
    for sink in sinks:
        out[sink.robot_id] = {**sink.counts, "written": sink.written,
                              "write_errors": sink.write_errors,
                              "transitions": transitions.get(sink.robot_id, [])}
        sink.close()
    print(json.dumps(out), flush=True)
    return 0


# ---- station alone (child) ------------------------------------------------------------------


def station_child(args: argparse.Namespace) -> int:
    from blackbox.station.follow import StationFollower
    from blackbox.station.store import StationStore
    from blackbox.transport.participant import TransportSettings

    store = StationStore.open(args.db, series_retention=args.duration + 3600)
    zenoh = None
    if args.zenoh:
        from blackbox.transport.zenoh_bus import ZenohSettings
        zenoh = ZenohSettings((args.zenoh,))
    follower = StationFollower(store, TransportSettings(args.domain, zenoh=zenoh), backfill=0)
    follower.start()
    print("ready", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    stop.wait(args.duration + 600)
    follower.stop()
    store.close()
    print(json.dumps({"received": follower.stats.received,
                      "rejected": follower.stats.rejected}), flush=True)
    return 0


# ---- the run (parent) -----------------------------------------------------------------------


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("CYCLONEDDS_URI", None)
    return env


def _has_web_station() -> bool:
    try:
        import blackbox.cli.station
        import blackbox.station.web.app  # noqa: F401
    except ImportError:
        return False
    return True


class WebClient:
    """Logs in to ``blackbox station`` as a viewer and times GETs of a page."""

    def __init__(self, url: str, user: str, password: str) -> None:
        import httpx

        self.http = httpx.Client(base_url=url, timeout=30.0, follow_redirects=False)
        form = self.http.get("/login")
        token = re.search(r'name="login_token"\s+value="([^"]+)"', form.text)
        data = {"username": user, "password": password, "next": "/"}
        if token:
            data["login_token"] = token.group(1)
        answer = self.http.post("/login", data=data)
        if answer.status_code not in (302, 303):
            raise RuntimeError(f"log-in refused: {answer.status_code} {answer.text[:300]}")

    def time_get(self, path: str) -> tuple[float, int, int]:
        t0 = time.perf_counter()
        answer = self.http.get(path)
        return time.perf_counter() - t0, answer.status_code, len(answer.content)


def thread_cpu(proc: Any) -> dict[str, float]:
    """CPU seconds of a process by thread name ("python" for its Python threads, Zenoh's
    own threads by their names: rx-0, tx-0, net-0, ...): where a station's time goes."""
    out: dict[str, float] = {}
    for thread in proc.threads():
        try:
            name = Path(f"/proc/{proc.pid}/task/{thread.id}/comm").read_text().strip()
        except OSError:
            continue
        name = re.sub(r"-\d+$", "", name)
        out[name] = out.get(name, 0.0) + thread.user_time + thread.system_time
    return out


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def flush_figures(web: WebClient) -> dict[str, float]:
    """The store's last flush as ``/metrics`` says: commit lag, seconds, rows."""
    out: dict[str, float] = {}
    for line in web.http.get("/metrics").text.splitlines():
        for name in ("commit_lag_seconds", "flush_seconds", "flush_rows"):
            if line.startswith(f"blackbox_station_store_{name} "):
                out[name] = float(line.split()[-1])
    return out


def station_behind(web: WebClient) -> bool:
    """Whether the station says it has not caught up with what it was sent (``/metrics``)."""
    for line in web.http.get("/metrics").text.splitlines():
        if line.startswith("blackbox_station_ingest_behind "):
            return line.split()[-1] not in ("0", "0.0")
    return False


def stored_counts(db: str, ids: list[str]) -> dict[str, dict[str, int]]:
    """What the station stored per robot (live events and chart values), read with the same
    SQL from SQLite or, for a ``postgresql://`` URL, with psycopg."""
    from blackbox.health.ids import robot_resource_id

    postgres = db.startswith(("postgresql://", "postgres://"))
    if postgres:
        import psycopg  # type: ignore[import-not-found]  # the storage backend's client

        con: Any = psycopg.connect(db)
        mark = "%s"
    else:
        con = sqlite3.connect(db)
        mark = "?"
    stored: dict[str, dict[str, int]] = {}
    try:
        for rid in ids:
            res = robot_resource_id(rid)
            ev = dict(con.execute(f"SELECT kind, count(*) FROM events WHERE resource_id = "
                                  f"{mark} AND origin = 'live' GROUP BY kind",
                                  (res,)).fetchall())
            stored[rid] = {
                "values": con.execute(f"SELECT count(*) FROM samples WHERE resource_id = "
                                      f"{mark}", (res,)).fetchone()[0],
                "exceedances": ev.get("exceedance", 0) + ev.get("state_change", 0),
                "failures": ev.get("failure", 0), "rectifications": ev.get("rectification", 0)}
    finally:
        con.close()
    return stored


def robots_heard(db: str) -> int:
    """Robots the station's database has heard from (SQLite file or PostgreSQL URL)."""
    try:
        if db.startswith(("postgresql://", "postgres://")):
            import psycopg

            with psycopg.connect(db) as con:
                row = con.execute("SELECT count(*) FROM robots WHERE last_heard IS NOT NULL"
                                  ).fetchone()
        else:
            con2 = sqlite3.connect(db, timeout=5.0)
            try:
                row = con2.execute("SELECT count(*) FROM robots WHERE last_heard IS NOT NULL"
                                   ).fetchone()
            finally:
                con2.close()
    except Exception:  # the station has not made its tables yet
        return 0
    return int(row[0]) if row else 0


SEEN_JS = """() => {
  window.__seen = [];
  const last = {};
  const record = () => {
    const now = Date.now();
    document.querySelectorAll('tr[data-robot]').forEach((tr) => {
      const status = tr.querySelector('[data-field=status]').textContent;
      if (last[tr.dataset.robot] !== status) {
        last[tr.dataset.robot] = status;
        window.__seen.push([tr.dataset.robot, status, now]);
      }
    });
  };
  record();
  document.addEventListener('station:state', record);
}"""


class FleetWatcher:
    """Debian's Chromium on the fleet page, filtered to the watched robots, noting when
    each row's status changes (the browser's own clock: the machine's)."""

    def __init__(self, url: str, user: str, password: str, search: str) -> None:
        from playwright.sync_api import sync_playwright

        self._pw = sync_playwright().start()
        self._browser = self._pw.chromium.launch(executable_path="/usr/bin/chromium")
        self.page = self._browser.new_page(base_url=url)
        self.page.goto("/login")
        self.page.fill("input[name=username]", user)
        self.page.fill("input[name=password]", password)
        self.page.click("button[type=submit]")
        self.page.wait_for_load_state()
        self.page.goto(f"/?search={search}")
        self.page.locator("body[data-live=open]").wait_for(timeout=30_000)
        self.page.evaluate(SEEN_JS)

    def wait(self, seconds: float) -> None:
        self.page.wait_for_timeout(seconds * 1000)

    def load_times(self, repeat: int = 5) -> list[float]:
        """Seconds from navigating to the whole fleet page to its ``load`` event."""
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            self.page.goto("/", wait_until="load")
            times.append(time.perf_counter() - t0)
        return times

    def seen(self) -> list[tuple[str, str, float]]:
        """(robot, status, when) of every change of a watched row (before navigating)."""
        return [(r, s, t / 1000) for r, s, t in self.page.evaluate("window.__seen")]

    def close(self) -> None:
        self._browser.close()
        self._pw.stop()


class CommitWatcher:
    """Looks every ``every`` s at the watched robots' derived status changes in the
    station's database (``status_changes``, the robot's own row): when each became
    visible, committed. Why: it splits a fault -> colour change into the station's
    ingest and write (robot -> committed) and the page's part (committed -> browser)."""

    def __init__(self, db: str, robots: list[str], every: float = 0.05) -> None:
        from blackbox.health.ids import robot_resource_id

        self.db = db
        self.every = every
        self.names = {robot_resource_id(r): r for r in robots}
        self.seen: list[tuple[str, str, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        postgres = self.db.startswith(("postgresql://", "postgres://"))
        mark = "%s" if postgres else "?"
        ids = ", ".join(str(i) for i in self.names)
        sql = (f"SELECT id, resource_id, status FROM status_changes WHERE instance_id = -1 "
               f"AND resource_id IN ({ids}) AND id > {mark} ORDER BY id")
        last = 0
        con: Any = None
        while not self._stop.wait(self.every):
            try:
                if con is None:
                    if postgres:
                        import psycopg

                        con = psycopg.connect(self.db, autocommit=True)
                    else:
                        con = sqlite3.connect(self.db, timeout=5.0)
                rows = con.execute(sql, (last,)).fetchall()
            except Exception:  # the station has not made its tables yet
                continue
            now = time.time()
            for row_id, rid, status in rows:
                last = max(last, int(row_id))
                self.seen.append((self.names[int(rid)], str(status), now))
        if con is not None:
            con.close()

    def close(self) -> list[tuple[str, str, float]]:
        self._stop.set()
        self._thread.join(timeout=10)
        return self.seen


def delays_after(published: dict[str, Any], seen: list[tuple[str, str, float]],
                 faulty: bool) -> tuple[list[float], int]:
    """Seconds from each fault start (``faulty``) or end of a watched robot to the first
    status of its row in ``seen`` that shows it (before its next change), and how many
    never did."""
    delays: list[float] = []
    missed = 0
    for robot, p in published.items():
        changes = p.get("transitions") or []
        for k, (t, now_faulty) in enumerate(changes):
            if now_faulty != faulty:
                continue
            end = changes[k + 1][0] if k + 1 < len(changes) else float("inf")
            shown = [at for r, status, at in seen if r == robot and t <= at < end
                     and (status != "OPERATIONAL") == faulty]
            if shown:
                delays.append(shown[0] - t)
            else:
                missed += 1
    return sorted(delays), missed


def _p99(delays: list[float]) -> float:
    return delays[min(len(delays) - 1, math.ceil(0.99 * len(delays)) - 1)]


def _figures(delays: list[float], missed: int) -> str:
    if not delays:
        return f"nothing seen ({missed} missed)"
    return (f"{len(delays)} changes, median {statistics.median(delays):.2f} s, p99 "
            f"{_p99(delays):.2f} s, max {delays[-1]:.2f} s; not shown before the next "
            f"change: {missed}")


def colour_changes(published: dict[str, Any], seen: list[tuple[str, str, float]],
                   committed: list[tuple[str, str, float]] | None = None) -> str:
    """Fault published by a watched robot -> its row's colour in Chromium (and, with
    ``committed``, -> its status committed in the station's database); fault end -> the
    row green again, separately: the robot itself reports OPERATIONAL only after
    ``clear_after`` (3) good observations in a row, 2 s after the fault ends at 1 Hz
    (``blackbox.health.status``), so that is a floor the station cannot cut."""
    lines = [f"fault -> colour change in Chromium ({len({r for r, *_ in seen})} watched "
             f"robots): {_figures(*delays_after(published, seen, True))}"]
    if committed is not None:
        lines.append("fault -> status committed in the database (looked at every 50 ms): "
                     + _figures(*delays_after(published, committed, True)))
    lines.append("fault end -> green again in Chromium (the robot reports it 2 s after, "
                 "by its hysteresis): " + _figures(*delays_after(published, seen, False)))
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=20)
    p.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    p.add_argument("--processes", type=int, default=4, help="processes the robots run in")
    p.add_argument("--interval", type=float, default=1.0, help="observation interval (s)")
    p.add_argument("--fault-every", type=float, default=30.0)
    p.add_argument("--fault-length", type=float, default=6.0)
    p.add_argument("--station", choices=["auto", "web", "core"], default="auto")
    p.add_argument("--domain", type=int, default=60 + os.getpid() % 40)
    p.add_argument("--keep", action="store_true", help="keep the station database")
    p.add_argument("--zenoh", nargs="?", const="router", default="",
                   help="robots and station meet through a Zenoh router (in this process, "
                        "on 127.0.0.1) instead of DDS")
    p.add_argument("--routers", type=int, default=0,
                   help="Zenoh routers of the robots, joined to the station's (default: "
                        "the station's own router carries them all)")
    p.add_argument("--db", default="",
                   help="the station's database: a file (SQLite; default a temporary one) or "
                        "postgresql://... (passed to blackbox station --db as it is)")
    p.add_argument("--watch", type=int, default=10,
                   help="robots whose fault -> colour change Chromium times on the fleet page "
                        "(0: no browser)")
    p.add_argument("--robots-child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--station-child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--ids", default="", help=argparse.SUPPRESS)
    p.add_argument("--index", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--watch-ids", dest="watch_ids", default="", help=argparse.SUPPRESS)
    p.add_argument("--clock-offset", type=float, default=0.0, help=argparse.SUPPRESS)
    p.add_argument("--fault-start", type=float, default=0.0, help=argparse.SUPPRESS)
    p.add_argument("--matched", action="store_true",
                   help="DDS: robots start publishing only once the station's readers "
                        "matched them all (what is lost then is delivery, not discovery)")
    args = p.parse_args()
    if args.robots_child:
        return robots_child(args)
    if args.station_child:
        return station_child(args)

    import psutil

    mode = args.station
    if mode == "auto":
        mode = "web" if _has_web_station() else "core"
    work = Path(tempfile.mkdtemp(prefix="station-fleet-"))
    db = args.db or str(work / "station.db")
    routers: list[Any] = []
    bus_args: list[str] = ["--domain", str(args.domain)]
    robot_routers: list[str] = []
    if args.zenoh:
        from blackbox.transport.zenoh_router import RouterSettings, open_router

        # the lightweight robots share one session per process (benchmarks/fleet_sim.py),
        # so one router carries them all; --routers N spreads them over N routers joined
        # to the station's one, as sites would
        for_robots = args.routers or 1
        count = for_robots + 1 if for_robots > 1 else 1
        endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in range(count)]
        for i, endpoint in enumerate(endpoints):
            routers.append(open_router(RouterSettings((endpoint,),
                                                      connect=() if i == 0 else (endpoints[0],))))
        args.zenoh = endpoints[0]
        bus_args = ["--zenoh", args.zenoh]
        robot_routers = endpoints[1:] or endpoints
    py = sys.executable
    web: WebClient | None = None
    password = "bench-" + os.urandom(8).hex()
    if mode == "web":
        subprocess.run([py, "-m", "blackbox", "station", "user", "add", "bench", "--role",
                        "viewer", "--db", str(db)], input=password + "\n", text=True,
                       check=True, capture_output=True, env=_env())
        ready = work / "url"
        station = subprocess.Popen(
            [py, "-m", "blackbox", "station", "--db", str(db), "--bind", "127.0.0.1:0",
             *bus_args, "--ready-file", str(ready)],
            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while not ready.exists() and time.monotonic() < deadline and station.poll() is None:
            time.sleep(0.1)
        if not ready.exists():
            print("station did not start:", station.stderr.read() if station.stderr else "",
                  file=sys.stderr)
            return 1
        url = ready.read_text().strip()
        web = WebClient(url, "bench", password)
    else:
        station = subprocess.Popen([py, str(HERE), "--station-child", "--db", str(db),
                                    *bus_args, "--duration", str(args.duration)],
                                   env=_env(), stdout=subprocess.PIPE, text=True)
        assert station.stdout is not None
        if station.stdout.readline().strip() != "ready":
            return 1
    proc = psutil.Process(station.pid)
    time.sleep(2.0)  # the station's readers exist before the first robot writes

    ids = [f"fleet-{i:04d}" for i in range(args.robots)]
    watched = ids[:min(args.watch, 10)] if web is not None else []
    browser = FleetWatcher(url, "bench", password, "fleet-000") if watched else None
    commits = CommitWatcher(str(db), watched) if watched else None
    size = math.ceil(len(ids) / args.processes)
    groups = [ids[i:i + size] for i in range(0, len(ids), size)]
    robots = []
    for index, group in enumerate(groups):
        if robot_routers:  # Zenoh: lightweight robots, one session per process
            robots.append(subprocess.Popen(
                [py, str(FLEET_SIM), "--zenoh", robot_routers[index % len(robot_routers)],
                 "--ids", ",".join(group), "--index", str(ids.index(group[0])),
                 "--watch-ids", ",".join(watched), "--duration", str(args.duration),
                 "--interval", str(args.interval), "--fault-every", str(args.fault_every),
                 "--fault-length", str(args.fault_length), "--wait-go"],
                env=_env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True))
            continue
        child = subprocess.Popen([py, str(HERE), "--robots-child", "--ids", ",".join(group),
                                  *bus_args, "--watch-ids", ",".join(watched),
                                  *(["--matched"] if args.matched else []), "--duration",
                                  str(args.duration), "--interval", str(args.interval),
                                  "--fault-every", str(args.fault_every), "--fault-length",
                                  str(args.fault_length), "--index", str(index)],
                                 env=_env(), stdout=subprocess.PIPE, text=True)
        robots.append(child)
    for child in robots:
        assert child.stdout is not None
        if child.stdout.readline().strip() != "ready":
            return 1
    if robot_routers:
        # Zenoh: each robot declares 15 publishers (a cache, a liveliness token and
        # heartbeats each); the router and the station take time to learn 15,000 of them,
        # during which nothing is routed. Measure once the station has heard every robot.
        heard_after = time.monotonic()
        deadline = heard_after + HEARD_TIMEOUT
        heard = 0
        while time.monotonic() < deadline:
            heard = robots_heard(db)
            if heard >= args.robots:
                break
            time.sleep(1.0)
        heard_after = time.monotonic() - heard_after
        print(f"station heard {heard} of {args.robots} robots {heard_after:.0f} s after all "
              "robot sessions reached the router", flush=True)
        for child in robots:
            if child.stdin is not None:
                child.stdin.write("go\n")
                child.stdin.flush()

    cpu0 = proc.cpu_times()
    threads0, router0 = thread_cpu(proc), thread_cpu(psutil.Process())
    t0 = time.monotonic()
    rss: list[int] = []
    page_times: list[float] = []
    page_sizes: list[int] = []
    page_errors = 0
    next_page = t0 + 10.0
    flushes: list[dict[str, float]] = []
    # Zenoh robots close 250 sinks each after their run (50 ms each): not part of the run
    run_end = t0 + args.duration + 2.0 if robot_routers else math.inf
    while any(c.poll() is None for c in robots) and time.monotonic() < run_end:
        if browser is not None:
            browser.wait(1.0)
        else:
            time.sleep(1.0)
        rss.append(proc.memory_info().rss)
        if web is not None:
            flushes.append(flush_figures(web))
        if web is not None and time.monotonic() >= next_page:
            next_page += 10.0
            seconds, status, size = web.time_get("/")
            if status == 200:
                page_times.append(seconds)
                page_sizes.append(size)
            else:
                page_errors += 1
    elapsed = time.monotonic() - t0
    cpu1 = proc.cpu_times()
    threads1, router1 = thread_cpu(proc), thread_cpu(psutil.Process())
    published: dict[str, dict[str, Any]] = {}
    fleet_cpu = 0.0
    for child in robots:
        out, _ = child.communicate(timeout=120)
        report = json.loads(out.strip().splitlines()[-1])
        if "robots" in report:  # benchmarks/fleet_sim.py
            fleet_cpu += report["cpu_seconds"]
            report = report["robots"]
        published.update(report)
    # the station may be behind: give it until what it stored stops growing and it says
    # it is no longer behind (a station starved of CPU on a loaded machine may store
    # nothing for seconds; late is not lost), at most DRAIN_TIMEOUT s, and say how long
    # that took
    drain_start = time.monotonic()
    stored_total = -1
    while time.monotonic() - drain_start < DRAIN_TIMEOUT:
        time.sleep(3.0)
        now_total = sum(sum(c.values()) for c in stored_counts(db, ids).values())
        if now_total == stored_total and not (web is not None and station_behind(web)):
            break
        stored_total = now_total
    drained = time.monotonic() - drain_start
    seen = browser.seen() if browser is not None else []
    committed = commits.close() if commits is not None else None
    loads = browser.load_times() if browser is not None else []
    if browser is not None:
        browser.close()
    if web is not None:
        fleet_page = web.time_get("/")
        total = re.search(r'data-field="total"[^>]*>(\d+)<', web.http.get("/").text)
        robot_count = int(total.group(1)) if total else 0
        told = [line for line in web.http.get("/metrics").text.splitlines()
                if line.startswith(("blackbox_station_samples_dropped_total",
                                    "blackbox_station_ingest_behind",
                                    "blackbox_station_store_dropped",
                                    "blackbox_station_store_coalesced",
                                    "blackbox_station_values_coalesced"))]
    station.send_signal(signal.SIGINT)
    try:
        station.wait(timeout=60)
    except subprocess.TimeoutExpired:
        station.kill()

    for router in reversed(routers):
        router.close()
    stored = stored_counts(db, ids)

    cpu = (cpu1.user + cpu1.system - cpu0.user - cpu0.system) / elapsed * 100
    load = os.getloadavg()
    print(f"machine: {os.cpu_count()} cores, {psutil.virtual_memory().total / 2**30:.1f} GiB, "
          f"load average {load[0]:.1f} / {load[1]:.1f} at the end; "
          f"bus: {f'Zenoh, {len(routers)} routers' if args.zenoh else 'DDS'}; "
          f"database: {'PostgreSQL' if str(db).startswith('postgresql') else 'SQLite'}; "
          f"station: {mode}; robots: {args.robots} in {len(groups)} processes; "
          f"measured {elapsed:.0f} s")
    print(f"station CPU {cpu:.1f} % of one core ({100 * cpu / max(1, args.robots):.1f} % per "
          f"100 robots); RSS max {max(rss) / 2**20:.0f} MiB, last {rss[-1] / 2**20:.0f} MiB")
    by_thread = {k: threads1.get(k, 0.0) - threads0.get(k, 0.0) for k in threads1}
    print("station CPU by thread: " + ", ".join(
        f"{name} {100 * t / elapsed:.1f} %" for name, t in sorted(
            by_thread.items(), key=lambda kv: -kv[1]) if t > 0.005 * elapsed))
    if routers:
        zenoh_threads = sum(t - router0.get(k, 0.0) for k, t in router1.items()
                            if k != "python")
        print(f"Zenoh router(s) (threads of this process) {100 * zenoh_threads / elapsed:.1f} % "
              "of one core")
    if fleet_cpu:
        print(f"simulated fleet CPU {100 * fleet_cpu / elapsed:.1f} % of one core in "
              f"{len(groups)} processes ({100 * fleet_cpu / elapsed / args.robots * 100:.1f} % "
              f"per 100 robots)")
    kinds = ("values", "exceedances", "failures", "rectifications")
    total_pub = {k: sum(p[k] for p in published.values()) for k in kinds}
    total_sto = {k: sum(s[k] for s in stored.values()) for k in kinds}
    rows = sum(total_sto.values())
    print(f"ingested: {rows / elapsed:.0f} stored rows/s (values + events); all robots wrote "
          f"{sum(p['written'] for p in published.values()) / elapsed:.0f} DDS samples/s")
    print(f"{'':16}{'published':>12}{'stored':>12}{'dropped':>10}")
    for k in kinds:
        print(f"{k:16}{total_pub[k]:>12}{total_sto[k]:>12}{total_pub[k] - total_sto[k]:>10}")
    short = [r for r in ids if any(stored[r][k] < published[r][k] for k in kinds)]
    print(f"robots with anything missing: {len(short)}", ", ".join(short[:10]),
          "..." if len(short) > 10 else "")
    extra = [r for r in ids if any(stored[r][k] > published[r][k] for k in kinds)]
    if extra:
        print(f"robots with more stored than published (duplicates): {len(extra)}",
              ", ".join(extra[:10]), "..." if len(extra) > 10 else "")
    if web is not None:
        if page_times:
            print(f"fleet page ({args.robots} robots) while running: n={len(page_times)}, "
                  f"median {statistics.median(page_times) * 1000:.1f} ms, max "
                  f"{max(page_times) * 1000:.1f} ms, {statistics.mean(page_sizes) / 1024:.0f}"
                  f" KiB; errors {page_errors}")
        print(f"fleet page after the run: {fleet_page[0] * 1000:.1f} ms, status "
              f"{fleet_page[1]}, robots on the station: {robot_count}")
        print("what the station told (/metrics):", "; ".join(told))
        lags = sorted(f.get("commit_lag_seconds", 0.0) for f in flushes)
        secs = sorted(f.get("flush_seconds", 0.0) for f in flushes)
        rows_ = sorted(f.get("flush_rows", 0.0) for f in flushes)
        if lags:
            print(f"store's last flush, looked at every second (n={len(lags)}): commit lag "
                  f"median {statistics.median(lags):.2f} s, max {lags[-1]:.2f} s; flush "
                  f"median {statistics.median(secs) * 1000:.0f} ms, max "
                  f"{secs[-1] * 1000:.0f} ms; rows median {statistics.median(rows_):.0f}, "
                  f"max {rows_[-1]:.0f}")
    print(f"stored counted {drained:.0f} s after the robots stopped (until it stopped "
          "growing)")
    if loads:
        print(f"fleet page in Chromium after the run ({args.robots} robots), navigation to "
              f"load: {', '.join(f'{t * 1000:.0f}' for t in loads)} ms")
    if watched:
        print(colour_changes(published, seen, committed))
    if args.keep:
        print("station database:", db)
    return 0


if __name__ == "__main__":
    sys.exit(main())
