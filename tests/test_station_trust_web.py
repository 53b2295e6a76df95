"""Trust on first use in the page: an administrator confirms the key a robot signs with;
a viewer cannot, and nothing is trusted without the confirmation (real HTTP, real files)."""

from __future__ import annotations

import time
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from fastapi.testclient import TestClient

from blackbox.health.ids import robot_resource_id
from blackbox.station.auth import Role
from blackbox.station.enrolment import RobotKeys
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from blackbox.transport.auth import public_key_text
from station_support import Unreachable, quick_auth
from test_station_web_http import PASSWORD, csrf_of, log_in


class WithKeys(Unreachable):
    """Operations that must not be reached, and the station's trusted robots."""

    def __init__(self, keys: RobotKeys) -> None:
        self.robot_keys = keys


def test_an_admin_confirms_the_key_a_robot_was_seen_signing_with(tmp_path: Path) -> None:
    path = tmp_path / "station.db"
    store = StationStore.open(path)
    auth = quick_auth(path)
    keys = RobotKeys(path)
    auth.add_user("vera", PASSWORD, Role.VIEWER)
    auth.add_user("ada", PASSWORD, Role.ADMIN)
    rid = robot_resource_id("r1")
    store.heard(rid, time.time())
    store.put_robot_id(rid, "r1")
    assert store.flush(force=True)
    key = Ed25519PrivateKey.generate().public_key()
    keys.note_seen("r1", key)  # what the follower does when r1's first signature arrives
    with TestClient(create_app(auth, store, WithKeys(keys)),
                    base_url="http://127.0.0.1") as client:
        assert log_in(client, "vera") == 303
        page = client.get("/robot?r=r1").text
        assert f"Not enrolled: signs with key {public_key_text(key)}" in page
        assert 'id="enrol-robot"' not in page
        refused = client.post("/robot/enrol", data={"csrf_token": csrf_of(client),
                                                    "robot": "r1"}, follow_redirects=False)
        assert refused.status_code == 403 and keys.trusted("r1") is None
        client.cookies.clear()
        assert log_in(client, "ada") == 303
        assert 'id="enrol-robot"' in client.get("/robot?r=r1").text
        done = client.post("/robot/enrol", data={"csrf_token": csrf_of(client), "robot": "r1"},
                           follow_redirects=False)
        assert done.status_code == 303
        trusted = keys.trusted("r1")
        assert trusted is not None and trusted.public_key == public_key_text(key)
        assert trusted.source == "confirmed"
        assert "Not enrolled" not in client.get("/robot?r=r1").text
        assert [a.outcome for a in auth.audit_log() if a.action == "robot.enrol"] == [
            "ok", "refused"]
    keys.close()
    auth.close()
    store.close()
