"""The running black box (``blackbox run --dds``) seen from a station in another process:
the station sees the robot's entities, its injected fault as a failure, runs a built-in test
and fetches the recorded failures through a log request. Cyclone DDS on loopback."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from blackbox.transport.auth import RequestSigner
from blackbox.transport.ibit import request_ibit
from blackbox.transport.logservice import LogClient
from blackbox.transport.participant import Bus, TransportSettings
from isolation import fresh_domain

pytestmark = [pytest.mark.dds]

BLACKBOX = [sys.executable, "-m", "blackbox"]
THESIS = Path(__file__).resolve().parent.parent / "src/blackbox/configs/thesis.yaml"


def test_station_sees_state_runs_ibit_and_fetches_failures(tmp_path: Path) -> None:
    domain = fresh_domain()
    faults = tmp_path / "faults.yaml"
    faults.write_text("faults:\n  - {kind: kill, component: /usb_cam, start: 3, end: 8}\n")
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    key = tmp_path / "depot"
    assert subprocess.run([*BLACKBOX, "keygen", str(key)], capture_output=True).returncode == 0
    config = tmp_path / "robot.yaml"
    config.write_text(THESIS.read_text() + "\ntransport:\n  access:\n    stations:\n"
                      "      - {name: depot, public_key_file: depot.pub, may: [logs, ibit]}\n")
    box = subprocess.Popen([*BLACKBOX, "run", "--dds", "--domain", str(domain), "--quiet",
                            "--config", str(config),
                            "--faults", str(faults), "--record", str(tmp_path / "bb.db"),
                            "--duration", "25"], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        listen = subprocess.run([*BLACKBOX, "listen", "--domain", str(domain), "--json",
                                 "--duration", "10"], env=env, capture_output=True, text=True,
                                timeout=60)
        assert listen.returncode == 0, listen.stderr
        states = [json.loads(line) for line in listen.stdout.splitlines() if line.strip()]
        robot = states[-1]["robots"]["thesis-robot"]
        assert {"/usb_cam", "/audio_capture", "/Signal_generator"} <= set(robot["entities"])
        failures = [e for s in states for e in s["robots"].get("thesis-robot", {}).get(
            "events", []) if "failure" in json.dumps(e)]
        assert any("/usb_cam" in json.dumps(e) for e in failures), robot["events"]

        bus = Bus.open(TransportSettings(domain))
        try:
            signer = RequestSigner.from_file(key)
            result = request_ibit(bus, "thesis-robot", timeout=10.0, signer=signer)
            assert result is not None, "no run_IBIT answer"
            assert result.A_observations >= 10
            answer = LogClient(bus, signer=signer).request("thesis-robot", kinds=["failure"],
                                                           timeout=10.0)
        finally:
            bus.close()
        logged = json.dumps([e for e in answer.entries])
        assert "/usb_cam" in logged
    finally:
        box.send_signal(signal.SIGINT)
        try:
            box.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            box.kill()
    assert box.returncode == 0
