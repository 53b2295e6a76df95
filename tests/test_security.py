"""Who may read the log and run the built-in test (issue 13): signed requests, per-station
keys, request fields within bounds. The DDS tests run the black box and the stations as
separate processes over Cyclone DDS on loopback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.health.types import C_Log_Request, T_DateTimeType, T_IdentifierType
from blackbox.transport.auth import (
    AccessPolicy,
    RequestSigner,
    RequestVerifier,
    StationAccess,
)
from blackbox.transport.logservice import check_request, request_fields
from isolation import fresh_domain
from station_support import dds_env
from test_dds_health import BlackBox, station_key

ROBOT = "thesis"


class Clock:
    def __init__(self) -> None:
        self.t = 1_700_000_000.0

    def __call__(self) -> float:
        return self.t


def keys() -> tuple[RequestSigner, RequestVerifier, Clock]:
    clock = Clock()
    depot = Ed25519PrivateKey.generate()
    viewer = Ed25519PrivateKey.generate()
    policy = AccessPolicy.of([StationAccess("depot", depot.public_key(),
                                            frozenset({"logs", "ibit"})),
                              StationAccess("viewer", viewer.public_key(), frozenset({"logs"}))])
    return (RequestSigner(depot, "depot", clock=clock),
            RequestVerifier(ROBOT, policy, clock=clock), clock)


REQUEST = {"request_id": [7, 1], "entity": "/usb_cam", "max_entries": 10}


# ---- the scheme, without a network -----------------------------------------------------------


def test_an_authorised_station_is_allowed_once_per_signature() -> None:
    signer, verifier, _ = keys()
    credential = signer.sign("logs", ROBOT, REQUEST)
    assert verifier.verify("logs", REQUEST, credential).allowed
    replay = verifier.verify("logs", REQUEST, credential)
    assert not replay.allowed and "replayed" in replay.reason


@pytest.mark.parametrize(("change", "reason"), [
    ("tampered field", "bad signature"),
    ("other robot", "bad signature"),
    ("other action", "bad signature"),
    ("expired", "expired"),
    ("unknown station", "unknown station"),
    ("unsigned", "unsigned request"),
    ("wrong key for the name", "bad signature"),
])
def test_anything_but_an_intact_fresh_signature_is_refused(change: str, reason: str) -> None:
    signer, verifier, clock = keys()
    action, robot, request = "logs", ROBOT, dict(REQUEST)
    if change == "other robot":
        robot = "another-robot"  # a request for another robot cannot be replayed here
    if change == "other action":
        action = "ibit"
    credential = signer.sign(action, robot, request)
    if change == "tampered field":
        request["max_entries"] = 0
    if change == "expired":
        clock.t += 31
    if change == "unknown station":
        credential = RequestSigner(Ed25519PrivateKey.generate(), "intruder",
                                   clock=clock).sign("logs", ROBOT, request)
    if change == "wrong key for the name":
        credential = RequestSigner(Ed25519PrivateKey.generate(), "depot",
                                   clock=clock).sign("logs", ROBOT, request)
    verdict = verifier.verify("logs", request, None if change == "unsigned" else credential)
    assert not verdict.allowed and reason in verdict.reason


def test_rights_are_per_station() -> None:
    _, verifier, clock = keys()
    viewer_key = Ed25519PrivateKey.generate()
    policy = AccessPolicy.of([StationAccess("viewer", viewer_key.public_key(),
                                            frozenset({"logs"}))])
    verifier = RequestVerifier(ROBOT, policy, clock=clock)
    viewer = RequestSigner(viewer_key, "viewer", clock=clock)
    assert verifier.verify("logs", REQUEST, viewer.sign("logs", ROBOT, REQUEST)).allowed
    verdict = verifier.verify("ibit", REQUEST, viewer.sign("ibit", ROBOT, REQUEST))
    assert not verdict.allowed and "may not ibit" in verdict.reason


def test_access_list_from_the_configuration(tmp_path: Path) -> None:
    key = station_key(tmp_path, "laptop")
    text = ("access:\n  stations:\n"
            "    - {name: laptop, public_key_file: laptop.pub, may: [logs]}\n"
            f"    - {{name: depot, public_key: \"{RequestSigner.from_file(key).public_key}\", "
            "may: [logs, ibit]}\n")
    policy = AccessPolicy.from_config(ConfigNode.parse(text, "robot.yaml")["access"], tmp_path)
    assert {n: sorted(s.may) for n, s in policy.stations.items()} == {
        "laptop": ["logs"], "depot": ["ibit", "logs"]}
    assert AccessPolicy.from_config(None, tmp_path).stations == {}  # nobody by default
    bad = "access:\n  stations:\n    - {name: x, public_key: \"bm90IGEga2V5\", may: [logs]}\n"
    with pytest.raises(ConfigError, match=r"robot.yaml:3:.*not an Ed25519 public key"):
        AccessPolicy.from_config(ConfigNode.parse(bad, "robot.yaml")["access"], tmp_path)
    bad = "access:\n  stations:\n    - {name: x, public_key_file: laptop.pub, may: [root]}\n"
    with pytest.raises(ConfigError, match="unknown right 'root'"):
        AccessPolicy.from_config(ConfigNode.parse(bad, "robot.yaml")["access"], tmp_path)


def test_keygen_never_overwrites_and_keeps_the_private_key_private(tmp_path: Path) -> None:
    key = station_key(tmp_path, "depot")
    assert key.stat().st_mode & 0o777 == 0o600
    again = subprocess.run([sys.executable, "-m", "blackbox", "keygen", str(key)],
                           capture_output=True, text=True, timeout=30)
    assert again.returncode == 2 and "is not overwritten" in again.stderr
    assert RequestSigner.from_file(key).station == "depot"


# ---- request fields within bounds ------------------------------------------------------------


def request(**fields: object) -> C_Log_Request:
    return C_Log_Request(A_requestID=T_IdentifierType(1, 1), **fields)  # type: ignore[arg-type]


def test_request_fields_have_bounds() -> None:
    assert check_request(request(A_maxEntries=10)) is None
    # What a peer declaring the field as int32 sends for -1: out of bounds, not "no limit".
    assert "A_maxEntries" in (check_request(request(A_maxEntries=2**32 - 1)) or "")
    assert "at most 256" in (check_request(request(A_entity="/a" * 200)) or "")
    assert "kinds" in (check_request(request(A_kinds=["sample"] * 17)) or "")
    late = T_DateTimeType(2_000_000_000, 0)
    early = T_DateTimeType(1_000_000_000, 0)
    assert "after" in (check_request(request(A_since=late, A_until=early)) or "")
    assert request_fields(request(A_maxEntries=3))["max_entries"] == 3


def test_request_logs_refuses_a_negative_maximum() -> None:
    done = subprocess.run([sys.executable, "-m", "blackbox", "request-logs", "--robot", "r",
                           "--max", "-5"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and "must be 0 (all) or 1..1000000" in done.stderr
    assert "Traceback" not in done.stderr


# ---- over DDS, between processes -----------------------------------------------------------


def request_logs(domain: int, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackbox", "request-logs", "--domain",
                           str(domain), "--robot", ROBOT, "--kind", "failure", "--timeout", "10",
                           *extra], capture_output=True, text=True, env=dds_env(), timeout=60)


@pytest.mark.dds
def test_only_an_authorised_station_gets_the_log_or_a_built_in_test(tmp_path: Path) -> None:
    from blackbox.transport.ibit import request_ibit
    from blackbox.transport.participant import Bus, TransportSettings

    domain = fresh_domain()
    depot = station_key(tmp_path, "depot")
    viewer = station_key(tmp_path, "viewer")
    intruder = station_key(tmp_path, "intruder")  # a valid key the robot does not list
    box = BlackBox(ROBOT, domain, store=tmp_path / "health.db",
                   allow={depot: "logs,ibit", viewer: "logs"})
    try:
        box.send("fault")
        unsigned = request_logs(domain)
        assert unsigned.returncode == 1 and "refused: unsigned request" in unsigned.stderr
        assert unsigned.stdout == ""
        stranger = request_logs(domain, "--key", str(intruder))
        assert stranger.returncode == 1 and "refused: unknown station" in stranger.stderr
        assert stranger.stdout == ""
        allowed = request_logs(domain, "--key", str(depot))
        assert allowed.returncode == 0, allowed.stderr
        assert '"/usb_cam"' in allowed.stdout and "1 entries" in allowed.stderr

        bus = Bus.open(TransportSettings(domain))
        try:
            refused = request_ibit(bus, ROBOT, timeout=10.0)  # the plain UCMS command
            assert refused is not None and refused.A_observations == 0
            assert refused.A_report[0].startswith("refused: unsigned request")
            only_logs = request_ibit(bus, ROBOT, timeout=10.0,
                                     signer=RequestSigner.from_file(viewer))
            assert only_logs is not None and "may not ibit" in only_logs.A_report[0]
            ran = request_ibit(bus, ROBOT, timeout=10.0, signer=RequestSigner.from_file(depot))
            assert ran is not None and ran.A_observations == 5
        finally:
            bus.close()
    finally:
        box.stop()
