"""Black box and listener as separate processes over Cyclone DDS on loopback.

Each test gets its own domain id (from the pid and a counter) so runs never cross-talk.
The black box side is ``tests/dds_blackbox_driver.py`` (DdsHealthSink plus the real
recorder); the station side is the real ``blackbox listen --json``.
"""

from __future__ import annotations

import json
import os
import queue
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import psutil
import pytest

from conftest import described
from isolation import fresh_domain
from station_support import DriverBlackBox, dds_env

pytestmark = pytest.mark.dds

HERE = Path(__file__).parent



def station_key(directory: Path, name: str = "depot") -> Path:
    """A station key pair made by ``blackbox keygen``: returns the private key file."""
    key = directory / name
    done = subprocess.run([sys.executable, "-m", "blackbox", "keygen", str(key), "--name", name],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    return key


class BlackBox(DriverBlackBox):
    """``allow``: a station's private key file (``blackbox keygen``) -> rights."""

    def __init__(self, robot: str, domain: int, store: Path | None = None,
                 partition: str = "blackbox", allow: dict[Path, str] | None = None) -> None:
        super().__init__(robot, domain, store, partition,
                         {Path(f"{key}.pub"): rights for key, rights in (allow or {}).items()})


class Listener:
    """``blackbox listen --json`` in its own process; a thread collects its state lines."""

    def __init__(self, domain: int, *extra: str, key: Path | None = None) -> None:
        env = dds_env()
        if key is not None:
            env["BLACKBOX_STATION_KEY"] = str(key)  # its backfill requests are signed
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "blackbox", "listen", "--domain", str(domain), "--json",
             "--duration", "90", *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.lines: queue.Queue[str] = queue.Queue()
        self.state: dict[str, Any] = {}
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line)

    def wait_for(self, predicate, timeout: float = 30.0) -> dict[str, Any]:
        """Read state lines until ``predicate(state)`` holds (bounded by ``timeout``: it
        includes the listener's start-up and DDS discovery, over 10 s on a loaded machine)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                if self.proc.poll() is not None:
                    break
                continue
            if line.strip():
                self.state = json.loads(line)
                if predicate(self.state):
                    return self.state
        ended = "" if self.proc.poll() is None else f" (the listener exited {self.proc.poll()})"
        raise AssertionError(f"waited {timeout:g} s for {described(predicate)}{ended}; "
                             f"last state: {json.dumps(self.state)[:2000]}")

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(timeout=10)


def entities(state: dict[str, Any], robot: str) -> dict[str, str]:
    r = state.get("robots", {}).get(robot)
    return {} if r is None else {n: e["health"] for n, e in r["entities"].items()}


def events(state: dict[str, Any], robot: str) -> list[dict[str, Any]]:
    r = state.get("robots", {}).get(robot)
    return [] if r is None else r["events"]


@pytest.fixture
def cleanup():
    procs: list[Any] = []
    yield procs
    for p in procs:
        if isinstance(p, BlackBox):
            try:
                p.stop()
            except Exception:
                p.proc.kill()
        else:
            p.kill()


def test_late_joiner_gets_the_full_state(cleanup):
    domain = fresh_domain()
    box = BlackBox("thesis", domain)
    cleanup.append(box)
    box.send("ok")
    box.send("fault")
    # The listener starts after everything was published: it sees it all from durability.
    listener = Listener(domain, "--backfill", "0")
    cleanup.append(listener)
    state = listener.wait_for(lambda s: entities(s, "thesis").get("/usb_cam")
                              == "NOT_OPERATIONAL")
    assert entities(state, "thesis") == {
        "thesis": "DEGRADED",  # one of three nodes down
        "/usb_cam": "NOT_OPERATIONAL",  # named by the diagnosis
        "/audio_capture": "OPERATIONAL",
        "/signal_generator": "OPERATIONAL",
    }
    chars = state["robots"]["thesis"]["characteristics"]
    assert chars["hz /usb_cam/image_raw [/usb_cam] period"] == 0.5
    assert chars["scores /signal [/signal_generator] score"] == 15.0
    assert len(chars) == 5


def test_restarted_listener_gets_state_again_and_missed_events_from_the_log(cleanup, tmp_path):
    domain = fresh_domain()
    key = station_key(tmp_path)
    box = BlackBox("thesis", domain, store=tmp_path / "health.db", allow={key: "logs"})
    cleanup.append(box)
    box.send("ok")
    first = Listener(domain, "--backfill", "0")
    cleanup.append(first)
    first.wait_for(lambda s: entities(s, "thesis").get("/usb_cam") == "OPERATIONAL")
    first.kill()
    box.send("fault")  # nobody is listening: the events are missed live
    second = Listener(domain, "--backfill", "300", key=key)
    cleanup.append(second)
    state = second.wait_for(lambda s: entities(s, "thesis").get("/usb_cam") == "NOT_OPERATIONAL"
                            and any(e["origin"] == "log" and e["kind"] == "failure"
                                    for e in events(s, "thesis")))
    from_log = [e for e in events(state, "thesis") if e["origin"] == "log"]
    assert {e["kind"] for e in from_log} == {"diagnosis", "exceedance", "failure"}
    failure = next(e for e in from_log if e["kind"] == "failure")
    assert failure["entity"] == "/usb_cam"
    assert "camera publishes too slowly" in failure["text"]


def test_live_events_reach_a_connected_listener(cleanup):
    domain = fresh_domain()
    box = BlackBox("thesis", domain)
    cleanup.append(box)
    box.send("ok")
    listener = Listener(domain, "--backfill", "0")
    cleanup.append(listener)
    listener.wait_for(lambda s: entities(s, "thesis").get("/usb_cam") == "OPERATIONAL")
    box.send("fault")
    # events of different kinds travel on different topics: wait for all three
    state = listener.wait_for(lambda s: len(events(s, "thesis")) >= 3)
    kinds = sorted(e["kind"] for e in events(state, "thesis"))
    assert kinds == ["diagnosis", "exceedance", "failure"]
    assert all(e["origin"] == "live" for e in events(state, "thesis"))


def test_two_black_boxes_on_one_domain_are_kept_apart(cleanup):
    domain = fresh_domain()
    a = BlackBox("alpha", domain)
    b = BlackBox("bravo", domain)
    hidden = BlackBox("charlie", domain, partition="other-fleet")
    cleanup.extend([a, b, hidden])
    a.send("fault")
    b.send("ok")
    hidden.send("fault")
    listener = Listener(domain, "--backfill", "0")
    cleanup.append(listener)
    state = listener.wait_for(lambda s: entities(s, "alpha").get("/usb_cam") == "NOT_OPERATIONAL"
                              and entities(s, "bravo").get("/usb_cam") == "OPERATIONAL")
    assert "charlie" not in state["robots"]  # another partition
    assert entities(state, "bravo")["bravo"] == "OPERATIONAL"
    assert entities(state, "alpha")["alpha"] == "DEGRADED"


def test_log_request_is_answered_only_by_the_addressed_robot(cleanup, tmp_path):
    domain = fresh_domain()
    key = station_key(tmp_path)
    a = BlackBox("alpha", domain, store=tmp_path / "a.db", allow={key: "logs"})
    b = BlackBox("bravo", domain, store=tmp_path / "b.db", allow={key: "logs"})
    cleanup.extend([a, b])
    a.send("fault")
    b.send("ok")
    out = tmp_path / "alpha.jsonl"
    done = subprocess.run(
        [sys.executable, "-m", "blackbox", "request-logs", "--domain", str(domain), "--robot",
         "alpha", "--kind", "failure", "--out", str(out), "--key", str(key)],
        capture_output=True, text=True, env=dds_env(), timeout=30)
    assert done.returncode == 0, done.stderr
    entries = [json.loads(line) for line in out.read_text().splitlines()]
    assert [e["payload"]["components"] for e in entries] == [["/usb_cam"]]
    assert "1 entries" in done.stderr


def _udp_ports(pid: int) -> list[int]:
    return sorted({c.laddr.port for c in psutil.Process(pid).net_connections(kind="udp")})


def test_foreign_and_garbage_samples_do_not_crash_the_listener(cleanup):
    domain = fresh_domain()
    box = BlackBox("thesis", domain)
    cleanup.append(box)
    box.send("ok")
    listener = Listener(domain, "--backfill", "0")
    cleanup.append(listener)
    listener.wait_for(lambda s: entities(s, "thesis").get("/usb_cam") == "OPERATIONAL")
    # A different type on a UCMS topic name, written by a third process.
    intruder = subprocess.run(
        [sys.executable, str(HERE / "dds_intruder.py"), str(domain)],
        capture_output=True, text=True, env=dds_env(), timeout=30)
    assert intruder.returncode == 0, intruder.stderr
    # Raw garbage datagrams at every UDP port the listener has open.
    ports = _udp_ports(listener.proc.pid)
    assert ports
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for port in ports:
            for payload in (b"", b"RTPS\x02\x01", os.urandom(200), b"RTPS" + os.urandom(60)):
                s.sendto(payload, ("127.0.0.1", port))
    box.send("fault")
    state = listener.wait_for(lambda s: entities(s, "thesis").get("/usb_cam")
                              == "NOT_OPERATIONAL")
    assert listener.proc.poll() is None
    assert entities(state, "thesis")["/audio_capture"] == "OPERATIONAL"
    # The intruder's well-formed but meaningless samples name no robot: they are reported
    # as a problem and not shown as a robot.
    state = listener.wait_for(lambda s: any("resource id 12345" in p for p in s["problems"]),
                              timeout=15.0)
    assert set(state["robots"]) == {"thesis"}


def test_run_ibit_evaluates_and_answers_with_the_reference_number(cleanup, monkeypatch,
                                                                  tmp_path):
    from blackbox.transport.auth import RequestSigner
    from blackbox.transport.ibit import request_ibit
    from blackbox.transport.participant import Bus, TransportSettings

    monkeypatch.delenv("CYCLONEDDS_URI", raising=False)
    domain = fresh_domain()
    key = station_key(tmp_path)
    box = BlackBox("thesis", domain, allow={key: "ibit"})
    cleanup.append(box)
    box.send("fault")
    bus = Bus.open(TransportSettings(domain))
    try:
        result = request_ibit(bus, "thesis", timeout=10.0,
                              signer=RequestSigner.from_file(key))
    finally:
        bus.close()
    assert result is not None
    assert (result.A_observations, result.A_failed) == (5, 0)  # the driver's test is healthy
    assert result.A_report[0] == "OK hz /usb_cam/image_raw [/usb_cam] GENERAL_OK"
