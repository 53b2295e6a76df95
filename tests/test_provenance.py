"""Signed robot health without a network: the station's gate against real signatures, the
robot's replay record in a real file, enrolment files and commands."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from blackbox.cli import main
from blackbox.health.ids import SourceIds
from blackbox.health.types import (
    C_Log_Reply,
    C_Monitored_Entity,
    T_HealthStatus,
    T_IdentifierType,
    datetime_of,
)
from blackbox.station.enrolment import EnrolmentError, RobotKeys, read_robots_file
from blackbox.station.trust import FIRST_SIGNATURE_WAIT, SIGNATURE_WAIT, SampleGate
from blackbox.transport.auth import (
    AccessPolicy,
    RequestSigner,
    RequestVerifier,
    StationAccess,
    generate_key_pair,
)
from blackbox.transport.provenance import SampleSigner, reply_signed_by

ENTITY = "C_Monitored_Entity"
FAILED = T_HealthStatus.L_HealthStatus_NOT_OPERATIONAL
OPERATIONAL = T_HealthStatus.L_HealthStatus_OPERATIONAL


def camera(status: T_HealthStatus, t: float) -> C_Monitored_Entity:
    return C_Monitored_Entity(A_sourceID=SourceIds("r1").of("entity", "/usb_cam"),
                              A_timeOfDataGeneration=datetime_of(t), A_healthStatus=status)


class Gate:
    """A gate trusting ``key`` for robot ``r1``; problems are collected."""

    def __init__(self, key: Ed25519PrivateKey) -> None:
        rid = SourceIds("r1").resource_id
        self.problems: list[tuple[str, str]] = []
        self.gate = SampleGate(lambda: {rid: ("r1", key.public_key())},
                               lambda robot, kind, text: self.problems.append((kind, text)))


def test_the_gate_shows_what_the_robot_signed_and_rejects_forgeries_and_replays() -> None:
    key = Ed25519PrivateKey.generate()
    signer = SampleSigner(key, "r1")
    g = Gate(key)
    failed = camera(FAILED, 100.0)
    g.gate.signature(signer.sign(ENTITY, failed))
    assert g.gate.offer(ENTITY, failed, 0.0)                     # signed: shown
    forged = camera(OPERATIONAL, 101.0)
    assert not g.gate.offer(ENTITY, forged, 0.0)                 # unsigned: held ...
    assert g.gate.released(1.0) == []
    assert g.gate.released(2.5) == []                            # ... then rejected
    assert g.gate.stats.unsigned == 1 and g.problems[-1][0] == "unsigned"
    intruder = SampleSigner(Ed25519PrivateKey.generate(), "r1")  # another key, same robot id
    g.gate.signature(intruder.sign(ENTITY, forged))
    assert not g.gate.offer(ENTITY, forged, 3.0)
    assert g.gate.stats.forged == 1 and g.problems[-1][0] == "forged"


def test_an_older_signed_state_is_refused_after_a_newer_one() -> None:
    key = Ed25519PrivateKey.generate()
    signer = SampleSigner(key, "r1", clock=iter([10.0, 20.0, 30.0]).__next__)
    g = Gate(key)
    operational, failed = camera(OPERATIONAL, 10.0), camera(FAILED, 20.0)
    for sample in (operational, failed):                         # both shown, in order
        g.gate.signature(signer.sign(ENTITY, sample))
        assert g.gate.offer(ENTITY, sample, 0.0)
    assert not g.gate.offer(ENTITY, operational, 0.0)            # replayed by a spoofer
    assert g.gate.stats.replayed == 1 and g.problems[-1][0] == "replayed"
    assert g.gate.offer(ENTITY, failed, 0.0)                     # the same state again: fine
    late = camera(OPERATIONAL, 15.0)                             # signed earlier, came late
    g.gate.signature(SampleSigner(key, "r1", clock=lambda: 15.0).sign(ENTITY, late))
    assert not g.gate.offer(ENTITY, late, 0.0)
    assert g.gate.stats.superseded == 1 and g.gate.stats.replayed == 1


def test_states_are_shown_in_order_and_a_lost_signature_is_no_alarm() -> None:
    key = Ed25519PrivateKey.generate()
    signer = SampleSigner(key, "r1", clock=iter([1.0, 2.0, 3.0]).__next__)
    g = Gate(key)
    first, lost, last = (camera(s, t) for s, t in ((FAILED, 1.0), (OPERATIONAL, 2.0),
                                                    (FAILED, 3.0)))
    first_sig = signer.sign(ENTITY, first)
    signer.sign(ENTITY, lost)                                    # this signature is lost
    g.gate.signature(signer.sign(ENTITY, last))
    assert not g.gate.offer(ENTITY, first, 0.0)                  # its signature is late
    assert not g.gate.offer(ENTITY, lost, 0.0)
    assert not g.gate.offer(ENTITY, last, 0.0)                   # waits behind the first
    g.gate.signature(first_sig)
    assert g.gate.released(0.5) == [(ENTITY, first), (ENTITY, last)]
    assert (g.gate.stats.superseded, g.gate.stats.unsigned, g.problems) == (1, 0, [])


def test_a_robot_that_is_not_enrolled_passes_unauthenticated() -> None:
    gate = SampleGate(dict, lambda *_: None)
    assert gate.offer(ENTITY, camera(OPERATIONAL, 1.0), 0.0)
    assert gate.stats.unauthenticated == 1


def test_a_signed_reply_verifies_only_unchanged_and_with_the_robots_key() -> None:
    key = Ed25519PrivateKey.generate()
    reply = C_Log_Reply(A_requestID=T_IdentifierType(7, 9), A_entries=['{"id": 1}'])
    SampleSigner(key, "r1").seal("BlackBox_Log_Reply", reply)
    assert reply_signed_by(key.public_key(), "r1", "BlackBox_Log_Reply", reply)
    assert not reply_signed_by(key.public_key(), "r2", "BlackBox_Log_Reply", reply)
    assert not reply_signed_by(Ed25519PrivateKey.generate().public_key(), "r1",
                               "BlackBox_Log_Reply", reply)
    reply.A_entries = ['{"id": 2}']
    assert not reply_signed_by(key.public_key(), "r1", "BlackBox_Log_Reply", reply)


def verifier(tmp_path: Path, station: RequestSigner) -> RequestVerifier:
    access = StationAccess(station.station, station.key.public_key(), frozenset({"ibit"}))
    return RequestVerifier("r1", AccessPolicy.of([access]), nonce_file=tmp_path / "nonces")


def test_accepted_request_nonces_survive_a_restart_of_the_robot(tmp_path: Path) -> None:
    station = RequestSigner(Ed25519PrivateKey.generate(), "depot")
    request = {"reference": 1}
    captured = station.sign("ibit", "r1", request)
    assert verifier(tmp_path, station).verify("ibit", request, captured).allowed
    restarted = verifier(tmp_path, station)
    verdict = restarted.verify("ibit", request, captured)
    assert not verdict.allowed and verdict.reason == "replayed or malformed nonce"
    assert restarted.verify("ibit", request, station.sign("ibit", "r1", request)).allowed


def test_expired_nonces_are_dropped_from_the_record_at_start(tmp_path: Path) -> None:
    station = RequestSigner(Ed25519PrivateKey.generate(), "depot")
    old = f"{int((time.time() - 5) * 1e9)} {'a' * 32}\n"
    live = f"{int((time.time() + 60) * 1e9)} {'b' * 32}\n"
    (tmp_path / "nonces").write_text(old + live + "torn li")
    verifier(tmp_path, station)
    assert (tmp_path / "nonces").read_text() == live


def test_a_request_is_refused_when_its_nonce_cannot_be_recorded(tmp_path: Path) -> None:
    station = RequestSigner(Ed25519PrivateKey.generate(), "depot")
    v = verifier(tmp_path, station)
    (tmp_path / "nonces").unlink()
    (tmp_path / "nonces").mkdir()  # unwritable as a file, for root too
    verdict = v.verify("ibit", {}, station.sign("ibit", "r1", {}))
    assert not verdict.allowed and "cannot record" in verdict.reason


def test_a_robots_file_with_a_bad_line_names_file_and_line(tmp_path: Path) -> None:
    good = generate_key_pair(tmp_path / "r1.key", "r1").read_text()
    fleet = tmp_path / "fleet.txt"
    fleet.write_text(f"# the depot's robots\n{good}\ned25519 nonsense r2\n")
    with pytest.raises(EnrolmentError, match=r"fleet.txt:4: not an Ed25519 public key"):
        read_robots_file(fleet)
    fleet.write_text(f"{good}{good}")
    with pytest.raises(EnrolmentError, match=r"fleet.txt:2: robot 'r1' is listed twice"):
        read_robots_file(fleet)
    fleet.write_text(good)
    assert read_robots_file(fleet) == [("r1", good.split()[1])]


def test_enrolment_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = str(tmp_path / "station.db")
    assert main(["keygen", str(tmp_path / "r1.key"), "--robot", "r1"]) == 0
    pub = str(tmp_path / "r1.key.pub")
    assert main(["station", "robots", "enrol", "r1", "--key", pub, "--db", db]) == 0
    assert main(["station", "robots", "enrol", "r2", "--seen", "--db", db]) == 2
    assert capsys.readouterr().err.strip().endswith("no signed sample of robot 'r2' seen yet")
    (tmp_path / "bad.pub").write_text("ed25519 !!! r3\n")
    assert main(["station", "robots", "enrol", "r3", "--key", str(tmp_path / "bad.pub"),
                 "--db", db]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    keys = RobotKeys(db)
    key = Ed25519PrivateKey.generate().public_key()
    keys.note_seen("r2", key)  # what the follower does when r2's signatures arrive
    keys.close()
    assert main(["station", "robots", "enrol", "r2", "--seen", "--db", db]) == 0
    capsys.readouterr()
    assert main(["station", "robots", "list", "--db", db]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert [line.split("\t")[:2] for line in listed] == [["r1", "trusted"], ["r2", "trusted"]]
    assert main(["station", "robots", "remove", "r1", "--db", db]) == 0
    assert main(["station", "robots", "remove", "r1", "--db", db]) == 2


def test_two_keys_signing_for_one_robot_that_is_not_enrolled_are_flagged(
        tmp_path: Path) -> None:
    from blackbox.station.follow import StationFollower
    from blackbox.station.store import StationStore

    store = StationStore.open(tmp_path / "station.db")
    keys = RobotKeys(tmp_path / "station.db")
    follower = StationFollower(store, robot_keys=keys)  # not started: no network needed
    sample = camera(OPERATIONAL, 1.0)
    for signer in (SampleSigner(Ed25519PrivateKey.generate(), "r1") for _ in range(2)):
        follower.gate.signature(signer.sign(ENTITY, sample))
    found = {p.source: p.message for p in store.problems()}
    assert "signatures with 2 different keys claim this robot" in found["two writers r1"]
    assert "blackbox station robots enrol r1 --seen" in found["not enrolled r1"]
    assert len([k for k in keys.seen() if k.robot_id == "r1"]) == 2
    keys.close()
    store.close()


def test_a_station_joining_late_holds_a_state_until_the_robots_first_signature_comes() -> None:
    key = Ed25519PrivateKey.generate()
    signer = SampleSigner(key, "r1")
    g = Gate(key)
    failed = camera(FAILED, 100.0)
    signature = signer.sign(ENTITY, failed)
    assert not g.gate.offer(ENTITY, failed, 0.0)   # the state came; its signature has not
    assert g.gate.released(SIGNATURE_WAIT + 3.0) == []  # no signature of r1 yet: still held
    assert g.gate.holding == 1 and g.gate.stats.unsigned == 0
    g.gate.signature(signature)                    # the signature reader matched at last
    assert g.gate.released(SIGNATURE_WAIT + 3.1) == [(ENTITY, failed)]
    assert (g.gate.stats.unsigned, g.problems) == (0, [])


def test_a_state_whose_robot_never_signs_is_rejected_after_the_first_signature_wait() -> None:
    g = Gate(Ed25519PrivateKey.generate())
    assert not g.gate.offer(ENTITY, camera(OPERATIONAL, 1.0), 0.0)
    assert g.gate.released(FIRST_SIGNATURE_WAIT - 0.1) == []
    assert g.gate.released(FIRST_SIGNATURE_WAIT) == []
    assert g.gate.stats.unsigned == 1 and g.problems[-1][0] == "unsigned"


def test_once_the_robot_signs_a_sample_held_since_before_gets_the_usual_wait_from_then() -> None:
    key = Ed25519PrivateKey.generate()
    signer = SampleSigner(key, "r1")
    g = Gate(key)
    forged = camera(OPERATIONAL, 1.0)
    assert not g.gate.offer(ENTITY, forged, 0.0)
    g.gate.signature(signer.sign(ENTITY, camera(FAILED, 2.0)))  # the robot signs from 10 s
    assert g.gate.released(10.0) == []
    assert g.gate.released(10.0 + SIGNATURE_WAIT - 0.1) == [] and g.gate.holding == 1
    assert g.gate.released(10.0 + SIGNATURE_WAIT) == []
    assert g.gate.stats.unsigned == 1 and g.gate.holding == 0
