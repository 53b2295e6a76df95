"""Robot health authenticated end to end (issue 24, item 2), between real processes over
Cyclone DDS on loopback into a real station database: a second participant pretending to
be an enrolled robot cannot turn it green, forged log replies are dropped, and a captured
built-in test request is refused after the robot restarts."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from blackbox.health.ids import SourceIds
from blackbox.health.types import C_IBIT_Request, C_IBIT_Result, C_Monitored_Entity_run_IBIT
from blackbox.station.enrolment import RobotKeys
from blackbox.station.follow import StationFollower
from blackbox.station.store import StationStore, UnknownRobot
from blackbox.transport.auth import generate_key_pair, load_private_key, to_wire
from blackbox.transport.ibit import RESULT_TOPIC, ibit_fields
from blackbox.transport.participant import Bus, TransportSettings, matched_both_ways
from blackbox.transport.provenance import reply_signed_by
from conftest import wait_until
from isolation import fresh_domain
from station_support import ScriptedBlackBox, dds_env, station_signer_for_tests

pytestmark = pytest.mark.dds

HERE = Path(__file__).parent
SPOOFER = HERE / "robot_spoofer.py"


@pytest.fixture(autouse=True)
def _loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CYCLONEDDS_URI", raising=False)


def wait(condition: Callable[[], Any], what: str = "", timeout: float = 20.0) -> Any:
    return wait_until(condition, what, timeout=timeout)


def health(store: StationStore, robot: str) -> dict[str, str]:
    try:
        return {e.name: e.reported_status for e in store.entities(robot)}
    except UnknownRobot:
        return {}


def diagnosis(store: StationStore, robot: str) -> tuple[str, ...] | None:
    try:
        return store.diagnosis(robot).components
    except UnknownRobot:
        return None


def problems(store: StationStore) -> dict[str, str]:
    return {p.source: p.message for p in store.problems(200)}


class Spoofer:
    """``tests/robot_spoofer.py`` in its own process, driven line by line."""

    def __init__(self, domain: int, robot: str) -> None:
        self.proc = subprocess.Popen([sys.executable, str(SPOOFER), str(domain), robot],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     env=dds_env())
        assert self._line() == "ready"

    def _line(self) -> str:
        assert self.proc.stdout is not None
        return self.proc.stdout.readline().strip()

    def send(self, command: str, answer: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        assert self._line() == answer

    def stop(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.close()
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait(timeout=10)


@contextmanager
def running(*parts: ScriptedBlackBox | Spoofer) -> Iterator[None]:
    try:
        yield
    finally:
        for part in parts:
            part.stop()


@contextmanager
def station(path: Path, domain: int, enrol: dict[str, Path] | None = None,
            **kwargs: Any) -> Iterator[tuple[StationStore, StationFollower]]:
    """A station database at ``path`` trusting ``enrol`` (robot id -> public key file)
    and a follower of ``domain`` into it."""
    store = StationStore.open(path)
    keys = RobotKeys(path)
    for robot, public in (enrol or {}).items():
        keys.enrol(robot, public.read_text())
    follower = StationFollower(store, TransportSettings(domain), station_id="test-station",
                               signer=station_signer_for_tests(), robot_keys=keys, **kwargs)
    follower.start()
    try:
        yield store, follower
    finally:
        follower.stop()
        keys.close()
        store.close()


def robot_key(tmp_path: Path, robot: str = "thesis") -> tuple[Path, Path]:
    key = tmp_path / f"{robot}.key"
    return key, generate_key_pair(key, robot)


def test_a_spoofer_turns_a_robot_that_is_not_enrolled_green_and_is_flagged(
        tmp_path: Path) -> None:
    """The attack the signatures stop, shown on a robot the station has not enrolled: the
    forged OPERATIONAL is shown (unauthenticated), and the second writer is flagged."""
    domain = fresh_domain()
    key, _ = robot_key(tmp_path)
    box = ScriptedBlackBox("thesis", domain, key=key)
    spoofer = Spoofer(domain, "thesis")
    with running(box, spoofer), station(tmp_path / "station.db", domain, backfill=0) as (
            store, follower):
        box.send("fault")
        wait(lambda: diagnosis(store, "thesis") == ("/usb_cam",))
        spoofer.send("green", "sent green")
        wait(lambda: health(store, "thesis").get("/usb_cam") == "OPERATIONAL",
             "the forged OPERATIONAL to be shown for a robot that is not enrolled")
        wait(lambda: diagnosis(store, "thesis") == ())
        wait(lambda: "two writers thesis" in problems(store))
        assert follower.gate.stats.unauthenticated > 0
        assert "not enrolled thesis" in problems(store)  # its key is offered for enrolment


def test_a_spoofer_cannot_turn_an_enrolled_robot_green(tmp_path: Path) -> None:
    domain = fresh_domain()
    key, public = robot_key(tmp_path)
    box = ScriptedBlackBox("thesis", domain, key=key)
    spoofer = Spoofer(domain, "thesis")
    with running(box, spoofer):
        box.send("fault")  # before the station starts: durable state and signatures arrive late
        with station(tmp_path / "station.db", domain, {"thesis": public}, backfill=0) as (
                store, follower):
            wait(lambda: diagnosis(store, "thesis") == ("/usb_cam",))
            camera = health(store, "thesis")["/usb_cam"]
            assert camera != "OPERATIONAL"
            spoofer.send("green", "sent green")
            trust = follower.gate.stats
            wait(lambda: trust.forged > 0 and trust.unsigned > 0 and follower.gate.holding == 0,
                 "the forged samples to be rejected")
            assert health(store, "thesis")["/usb_cam"] == camera
            assert diagnosis(store, "thesis") == ("/usb_cam",)
            assert not store.events("thesis", kinds=["rectification"]).events
            found = problems(store)
            assert "does not verify with the robot's enrolled key" in found["forged data thesis"]
            assert "without the robot's signature" in found["unsigned data thesis"]
            wait(lambda: "two writers thesis" in problems(store))
            assert follower.gate.stats.unauthenticated == 0
            for _ in range(3):  # what the robot itself signs still gets through (a status
                box.send("ok")  # clears after three good observations)
            wait(lambda: diagnosis(store, "thesis") == ())
            wait(lambda: health(store, "thesis").get("/usb_cam") == "OPERATIONAL")
            assert [e.origin for e in store.events("thesis", kinds=["rectification"]).events] \
                == ["live"]


def test_forged_log_replies_are_dropped_and_the_robots_own_answer_is_stored(
        tmp_path: Path) -> None:
    domain = fresh_domain()
    key, public = robot_key(tmp_path)
    box = ScriptedBlackBox("thesis", domain, store=tmp_path / "robot.db", key=key)
    spoofer = Spoofer(domain, "thesis")
    with running(box, spoofer):
        box.send("fault")
        spoofer.send("logs", "answering logs")
        # a station that starts now fetches what it missed: the spoofer races the robot
        with station(tmp_path / "station.db", domain, {"thesis": public}) as (store, follower):
            wait(lambda: [e.entity for e in store.events(
                "thesis", kinds=["failure"]).events if e.origin == "log"] == ["/usb_cam"],
                "the robot's own logged failure to be backfilled")
            wait(lambda: follower.stats.backfilled > 0)
            entities = {e.entity for e in store.events("thesis", limit=1000).events}
            assert "/forged_node" not in entities
            wait(lambda: follower.gate.stats.forged > 0, "the forged replies to be counted")
            assert "log reply chunks without the robot's signature were dropped" in \
                problems(store)["forged data thesis"]


def test_a_captured_ibit_request_is_refused_after_the_robot_restarts(tmp_path: Path) -> None:
    domain = fresh_domain()
    key, _ = robot_key(tmp_path)
    public = load_private_key(key).public_key()
    ids = SourceIds("thesis")
    command = C_Monitored_Entity_run_IBIT(A_recipientID=ids.robot(), A_sourceID=ids.robot(),
                                          A_referenceNum=4242)
    signer = station_signer_for_tests()
    captured = C_IBIT_Request(
        A_recipientID=command.A_recipientID, A_sourceID=command.A_sourceID,
        A_referenceNum=command.A_referenceNum,
        A_timeOfDataGeneration=command.A_timeOfDataGeneration,
        A_signed=to_wire(signer.sign("ibit", "thesis", ibit_fields(command))))
    bus = Bus.open(TransportSettings(domain))
    writer, reader = bus.writer("BlackBox_IBIT_Request"), bus.reader(RESULT_TOPIC)

    def answer_to(request: C_IBIT_Request) -> C_IBIT_Result:
        wait(lambda: matched_both_ways(writer, reader), "the robot's IBIT service to match")
        writer.write(request)
        results: list[C_IBIT_Result] = []

        def answered() -> bool:
            results.extend(r for r in reader.take(N=8) if isinstance(r, C_IBIT_Result)
                           and r.A_referenceNum == 4242)
            return bool(results)
        wait(answered, "the robot's answer")
        return results[0]

    try:
        box = ScriptedBlackBox("thesis", domain, key=key)
        with running(box):
            first = answer_to(captured)
            assert not any(line.startswith("refused") for line in first.A_report)
            assert reply_signed_by(public, "thesis", RESULT_TOPIC, first)
            assert answer_to(captured).A_report == ["refused: replayed or malformed nonce"]
        wait(lambda: not matched_both_ways(writer, reader), "the robot to leave")
        box = ScriptedBlackBox("thesis", domain, key=key)  # the same robot, restarted
        with running(box):
            again = answer_to(captured)
            assert again.A_report == ["refused: replayed or malformed nonce"]
            assert reply_signed_by(public, "thesis", RESULT_TOPIC, again)
        assert key.with_name(key.name + ".nonces").read_text().count("\n") == 1
    finally:
        bus.close()
    assert time.time() < captured.A_signed.A_expiresNs / 1e9, \
        "the request must still be unexpired for the refusal to prove replay protection"


def test_blackbox_run_with_a_key_is_shown_as_signed(tmp_path: Path) -> None:
    """The command line path: ``blackbox run --dds --key`` signs everything it publishes."""
    domain = fresh_domain()
    key, public = robot_key(tmp_path, "thesis-robot")
    run = subprocess.Popen([sys.executable, "-m", "blackbox", "run", "--source", "sim:thesis",
                            "--dds", "--domain", str(domain), "--quiet", "--key", str(key),
                            "--duration", "60"], env=dds_env(), stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    try:
        with station(tmp_path / "station.db", domain, {"thesis-robot": public},
                     backfill=0) as (store, follower):
            wait(lambda: health(store, "thesis-robot").get("/usb_cam") == "OPERATIONAL",
                 "the signed state of the simulated robot", timeout=40)
            trust = follower.gate.stats
            assert trust.verified > 0
            assert (trust.forged, trust.unsigned, trust.unauthenticated) == (0, 0, 0)
    finally:
        run.terminate()
        _, err = run.communicate(timeout=20)
    assert "Traceback" not in err, err[-2000:]


def test_a_signed_burst_is_shown_whole_without_false_alarms(tmp_path: Path) -> None:
    """Signatures keep up with the robot: 200 failures and 200 rectifications as fast as
    the robot makes them are all shown, none held back as unsigned."""
    domain = fresh_domain()
    key, public = robot_key(tmp_path)
    box = ScriptedBlackBox("thesis", domain, key=key)
    with running(box), station(tmp_path / "station.db", domain, {"thesis": public},
                               backfill=0) as (store, follower):
        box.send("ok")
        wait(lambda: "/usb_cam" in health(store, "thesis"), "the robot's entities")
        box.send("burst 200")

        def count(kind: str) -> int:
            return store.count_events("thesis", kinds=[kind])
        wait(lambda: count("failure") == 200 and count("rectification") == 200,
             "200 failures and 200 rectifications", timeout=60)
        wait(lambda: follower.gate.holding == 0, "nothing held")
        trust = follower.gate.stats
        assert (trust.forged, trust.unsigned, trust.replayed) == (0, 0, 0)
        assert not [p for p in store.problems() if "data thesis" in p.source]
