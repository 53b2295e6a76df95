"""A fault on a robot reaches the on-call webhook through the whole real chain: a scripted
black box publishing UCMS health over Cyclone DDS (loopback), the ``blackbox station
--alerts`` process following it, and a webhook receiver on 127.0.0.1 in the test. The
recovery sends ``resolved``; the station's ``/metrics`` counts the delivery."""

from __future__ import annotations

import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from alert_support import SECRET, rules_file, webhook_receiver
from conftest import wait_for
from isolation import fresh_domain
from station_support import DriverBlackBox, dds_env

pytestmark = [pytest.mark.dds, pytest.mark.slow]


def test_a_fault_on_a_robot_reaches_the_webhook_and_its_recovery_resolves_it(
        tmp_path: Path) -> None:
    domain = fresh_domain()
    with webhook_receiver() as hook:
        alerts = rules_file(tmp_path, f"""\
channels:
  oncall: {{type: webhook, url: "{hook.url}", secret: "{SECRET}"}}
rules:
  - name: camera
    match: {{robot: "tug-*", entity: /usb_cam, kind: failure}}
    send: oncall
""")
        ready = tmp_path / "url"
        env = {**dds_env(), "SCRAPE": "metrics token of the test"}
        station = subprocess.Popen(
            [sys.executable, "-m", "blackbox", "station", "--db", str(tmp_path / "s.db"),
             "--bind", "127.0.0.1:0", "--domain", str(domain), "--alerts", str(alerts),
             "--metrics-token-env", "SCRAPE", "--ready-file", str(ready)],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        robot = None
        try:
            assert wait_for(lambda: ready.exists() or station.poll() is not None, 60), \
                "waited 60 s for the station to serve"
            assert station.poll() is None, station.stderr.read() if station.stderr else ""
            url = ready.read_text().strip()
            robot = DriverBlackBox("tug-7", domain)
            robot.send("ok")
            robot.send("fault")
            got = hook.wait_for(1, timeout=30)[0]
            assert got.signed_by(SECRET)
            body = got.json
            assert (body["type"], body["alert"]["robot"], body["alert"]["entity"]) == \
                ("alert", "tug-7", "/usb_cam")
            robot.send("ok")
            resolved = hook.wait_for(2, timeout=30)[1].json
            assert (resolved["type"], resolved["alert"]["id"]) == ("resolved",
                                                                   body["alert"]["id"])

            def scraped() -> str:
                request = urllib.request.Request(
                    url + "metrics",
                    headers={"Authorization": f"Bearer {env['SCRAPE']}"})
                with urllib.request.urlopen(request, timeout=5) as reply:
                    return str(reply.read().decode())
            assert wait_for(lambda: 'blackbox_station_notifications_total{channel="oncall",'
                            'outcome="sent"} 2' in scraped(), 10), scraped()
        finally:
            if robot is not None:
                robot.stop()
            station.terminate()
            station.wait(timeout=30)
