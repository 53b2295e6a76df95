"""The recorder sink: policies applied, snapshots referenced, configuration, self-monitoring."""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import MessageArrival, TopicSchema
from blackbox.health.identity import EventId
from blackbox.model import BlackBoxEvent, Code, Diagnosis, Observation, Resource, State
from blackbox.record import ConfigVersion, Recorder, SnapshotConfig, Store
from blackbox.record.settings import RecorderSettings, SnapshotSettings, parse_size
from blackbox.record.store import Row

T0 = 1_700_000_000.0
OK = (State(1, "ok"),)
CAM = Resource(topic="/usb_cam/image_raw")
STRING = TopicSchema("/chatter", "std_msgs/String", "ros1", "string data",
                     "992ce8a1687cec8c8bd883ec73ca41d1")
THESIS = Path(__file__).resolve().parent.parent / "src/blackbox/configs/thesis.yaml"


def obs(t: float, code: Code = Code.GENERAL_OK, resource: Resource = CAM,
        period: float = 0.0667) -> Observation:
    return Observation(t, "hz", resource, code, OK if code == Code.GENERAL_OK else (),
                       {"period": period})


def wait_for(condition: Callable[[], bool], poke: Callable[[], None] = lambda: None,
             seconds: float = 20.0) -> None:
    """Bounded wait for the writer thread (not a timing assertion)."""
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, "the recorder did not get there"
        poke()
        time.sleep(0.02)


def entries(path: Path, **filters: object) -> list:
    with Store.open(path, readonly=True) as store:
        return list(store.query(**filters))  # type: ignore[arg-type]


def test_records_changes_samples_and_own_start_stop(tmp_path: Path) -> None:
    now = [T0]
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=0.05, snapshot=None),
                   robot_id="r1", clock=lambda: now[0])
    for i in range(130):
        now[0] = T0 + i
        rec.on_observations(now[0], [obs(now[0], Code.NO_STATE_FITS if 40 <= i < 42 else
                                         Code.GENERAL_OK)])
    rec.close()
    got = [(e.time - T0, e.kind) for e in entries(tmp_path / "log.db")]
    # Every second for 30 s after the fault at 40 (until 70), then 60 s after the last.
    boosted = [(float(t), "sample") for t in range(43, 70)]
    assert got == [(0.0, "blackbox_event"), (0.0, "observation"), (40.0, "exceedance"),
                   (41.0, "sample"), (42.0, "observation"), *boosted, (129.0, "sample"),
                   (129.0, "blackbox_event")]
    start, stop = entries(tmp_path / "log.db", kinds=["blackbox_event"])
    assert start.entity == "blackbox/recorder" and start.payload["event"] == "start"
    assert stop.payload == {"event": "stop", "dropped": 0}
    assert rec.health().code == Code.GENERAL_OK


def test_next_start_appends_to_the_same_log(tmp_path: Path) -> None:
    for run in range(2):
        rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=0.05, snapshot=None),
                       robot_id="r1")
        rec.on_observations(T0 + run, [obs(T0 + run, Code.GENERAL_OK, Resource(topic=f"/t{run}"))])
        rec.close()
    assert [e.entity for e in entries(tmp_path / "log.db", kinds=["observation"])] == \
        ["/t0", "/t1"]


def test_fault_snapshot_is_written_and_referenced_by_the_failure(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Reader

    now = [T0]
    ring = SnapshotConfig(before=2.0, after=1.0)
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=0.05,
                                    snapshot=SnapshotSettings(ring)),
                   robot_id="r1", clock=lambda: now[0], schema_lookup={"/chatter": STRING}.get)
    assert rec.wants_messages
    for i in range(60):  # 10 Hz chatter, evaluation at 1 Hz, fault at 3 s
        t = T0 + i * 0.1
        now[0] = t
        text = str(i).encode()
        data = struct.pack("<I", len(text)) + text
        rec.on_message(MessageArrival(t, "/chatter", "/talker", len(data), raw=lambda d=data: d))
        if i % 10 == 0:
            code = Code.NO_STATE_FITS if i >= 30 else Code.GENERAL_OK
            rec.on_observations(t, [obs(t, code)])
            if i == 30:
                rec.on_diagnosis(Diagnosis(t, (frozenset({"/usb_cam"}),), (obs(t, code),),
                                           "camera too slow"))
    rec.close()
    log = tmp_path / "log.db"
    (exceedance,) = entries(log, kinds=["exceedance"])
    (failure,) = entries(log, kinds=["failure"])
    (snapshot,) = entries(log, kinds=["snapshot"])
    name = exceedance.payload["snapshot"]
    assert failure.payload["snapshot"] == name == snapshot.payload["file"]
    assert failure.payload["category"] == "detection"
    assert failure.payload["components"] == ["/usb_cam"]
    assert snapshot.payload["messages"] == 31  # 1.0 s .. 4.0 s at 10 Hz
    with Reader(tmp_path / "log.db.snapshots" / name) as reader:
        assert reader.message_count == 31


def test_diagnosis_logged_on_change_and_failure_rectified(tmp_path: Path) -> None:
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=0.05, snapshot=None),
                   robot_id="r1")
    cam = frozenset({"/usb_cam"})
    for t, cands in [(1, ()), (2, (cam,)), (3, (cam,)), (4, ())]:
        rec.on_diagnosis(Diagnosis(T0 + t, cands))
    rec.close()
    diag = [e.payload["candidates"] for e in entries(tmp_path / "log.db", kinds=["diagnosis"])]
    assert diag == [[], [["/usb_cam"]], []]
    fail = [(e.payload["category"], e.payload["components"])
            for e in entries(tmp_path / "log.db", kinds=["failure"])]
    assert fail == [("detection", ["/usb_cam"]), ("rectification", ["/usb_cam"])]


def corrupt_log(log: Path) -> bytes:
    """A health log of ours whose pages after the header are garbage."""
    with Store.open(log) as store:
        store.append([Row(T0, "failure", None, None, {"components": ["/a"]})] * 50)
    data = bytearray(log.read_bytes())
    data[100:] = b"\x00garbage" * ((len(data) - 100) // 8) + b"\x00" * ((len(data) - 100) % 8)
    log.write_bytes(bytes(data))
    for extra in tmp_path_wal(log):
        extra.unlink()
    return bytes(data)


def tmp_path_wal(log: Path) -> list[Path]:
    return [p for p in (Path(f"{log}-wal"), Path(f"{log}-shm")) if p.exists()]


def test_corrupt_log_is_set_aside_and_a_new_one_started(tmp_path: Path) -> None:
    log = tmp_path / "log.db"
    garbage = corrupt_log(log)
    events: list[BlackBoxEvent] = []
    rec = Recorder(RecorderSettings(log, commit_interval=0.05, snapshot=None),
                   robot_id="r1", on_self_event=events.append)
    rec.on_observations(T0, [obs(T0)])
    rec.close()
    (aside,) = tmp_path.glob("log.db.corrupt-*")
    assert aside.read_bytes() == garbage
    assert [(e.kind, e.component) for e in events] == [("storage_corrupt", "blackbox/recorder")]
    assert "moved to log.db.corrupt-" in events[0].message
    kinds = [(e.kind, e.payload.get("event")) for e in entries(log)]
    assert ("blackbox_event", "storage_corrupt") in kinds and ("observation", None) in kinds


def test_imported_configuration_is_handed_over_without_restart(tmp_path: Path) -> None:
    log = tmp_path / "log.db"
    applied: list[ConfigVersion] = []
    rec = Recorder(RecorderSettings(log, commit_interval=0.05, snapshot=None),
                   robot_id="r1", on_config=applied.append)
    rec.record_config("observers: []\n", "startup")
    wait_for(lambda: rec.written >= 2)  # start event and startup configuration committed
    assert main(["log", "import", "--db", str(log), str(THESIS), "--note", "new thresholds"]) == 0
    wait_for(lambda: bool(applied), lambda: rec.on_observations(T0, []))
    rec.close()
    (version,) = applied
    assert version.version == 2 and version.source == "import"
    assert version.text == THESIS.read_text()
    configs = entries(log, kinds=["config"])
    assert [(c.payload["version"], c.payload["source"]) for c in configs] == \
        [(1, "startup"), (2, "import")]
    assert any(e.payload.get("event") == "config_applied" and e.payload["version"] == 2
               for e in entries(log, kinds=["blackbox_event"]))


def test_rejected_configuration_is_recorded(tmp_path: Path) -> None:
    log = tmp_path / "log.db"

    def refuse(version: ConfigVersion) -> None:
        raise ValueError("observer /x cannot be rebuilt")

    rec = Recorder(RecorderSettings(log, commit_interval=0.05, snapshot=None),
                   robot_id="r1", on_config=refuse)
    assert main(["log", "import", "--db", str(log), str(THESIS)]) == 0
    wait_for(lambda: any(e.payload.get("event") == "config_rejected"
                         for e in entries(log, kinds=["blackbox_event"])),
             lambda: rec.on_observations(T0, []))
    rec.close()


def test_invalid_import_is_refused_and_nothing_stored(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    log = tmp_path / "log.db"
    Store.open(log).close()
    bad = tmp_path / "bad.yaml"
    bad.write_text("observers:\n  - type: hz\n    topic: /a\n    filter: {type: meen}\n")
    assert main(["log", "import", "--db", str(log), str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml:4:" in err
    assert entries(log) == []


def test_from_config_reads_the_recorder_section(tmp_path: Path) -> None:
    node = ConfigNode.parse(
        "recorder:\n"
        "  path: data/health.db\n"
        "  budget: 2 GB\n"
        "  commit_interval: 0.5\n"
        "  policy:\n"
        "    interval: 30\n"
        "    on_fault: {interval: 0.5, duration: 10}\n"
        "    rules:\n"
        "      - {entity: /usb_cam*, characteristic: hz, interval: 5, states: {degraded: 1}}\n"
        "  snapshot:\n"
        "    format: mcap\n"
        "    before: 4\n"
        "    max_bytes: 16 MiB\n"
        "    keep_one_of: {/usb_cam/image_raw: 5}\n", "bb.yaml")
    (tmp_path / "data").mkdir()
    rec = Recorder.from_config(node["recorder"], "r1", tmp_path)
    try:
        assert rec.path == tmp_path / "data/health.db"
        assert rec.commit_interval == 0.5 and rec.snapshot_format == "mcap"
        assert rec.settings == RecorderSettings.from_config(node["recorder"], tmp_path)
        assert rec.retention.budget_bytes == 1_500_000_000  # 25 % kept for snapshots
        assert rec.ring is not None and rec.ring.config.max_bytes == 16 * 1024**2
        assert rec.ring.config.keep_one_of == {"/usb_cam/image_raw": 5}
        rule = rec.policy.rule_for("/usb_cam/image_raw", "hz")
        assert (rule.interval, rule.states, rule.on_fault.interval) == (5.0, {"degraded": 1.0},
                                                                      0.5)
        assert rec.policy.rule_for("/audio", "hz").interval == 30.0
    finally:
        rec.close()


@pytest.mark.parametrize(("text", "message"), [
    ("recorder: {budgte: 1}", "at recorder.budgte: unknown key 'budgte'; "
                              "did you mean 'budget'?"),
    ("recorder: {budget: 1 parsec}", "unknown size unit 'parsec'"),
    ("recorder: {snapshot: {format: bag}}", "unknown value 'bag'; expected one of ros1, mcap"),
    ("recorder: {policy: {rules: [{interval: 3}]}}", "a rule needs 'entity' or 'characteristic'"),
    ("recorder: {commit_interval: 0}", "must be >= 0.01"),
])
def test_from_config_errors_name_the_place(tmp_path: Path, text: str, message: str) -> None:
    node = ConfigNode.parse(text, "bb.yaml")
    with pytest.raises(ConfigError) as err:
        Recorder.from_config(node["recorder"], "r1", tmp_path)
    assert str(err.value).startswith("bb.yaml:1:")
    assert message in str(err.value)


def test_sizes() -> None:
    assert parse_size("1 GB") == 10**9
    assert parse_size("512MiB") == 512 * 1024**2
    assert parse_size("1000") == 1000


def test_bounded_queue_drops_samples_first_and_counts(tmp_path: Path) -> None:
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=30.0, snapshot=None,
                                    queue_limit=100),
                   robot_id="r1")
    # The writer commits every 30 s: everything below stays queued until close().
    for i in range(300):
        rec.on_observations(T0 + i * 60, [obs(T0 + i * 60, resource=Resource(topic="/a")),
                                          obs(T0 + i * 60, resource=Resource(topic=f"/n{i}"))])
    health = rec.health()
    assert health.values["dropped"] > 0
    rec.close()
    logged = entries(tmp_path / "log.db")
    counted = [e.payload for e in logged if e.payload.get("event") == "records_dropped"]
    # The log itself says what it lost, by kind: samples went first.
    assert counted and counted[-1]["total"] == rec.dropped
    by_kind = counted[-1]["by_kind"]
    # (how many depends on when the writer thread drains the queue: a loaded machine's
    # scheduling, so the bound is the order of dropping, not a count)
    assert set(by_kind) == {"sample", "observation"}
    assert by_kind["sample"] > by_kind["observation"]
    assert len(logged) - len(counted) + rec.dropped == 2 + 300 + 300  # start, stop, both


def test_logged_observation_payloads_are_complete_changes_and_lean_samples(
        tmp_path: Path) -> None:
    degraded = (State(2, "degraded"), State(5, "warm"))
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=0.05, snapshot=None),
                   robot_id="r1")
    rec.on_observations(T0, [Observation(T0, "hz", CAM, Code.GENERAL_OK, degraded,
                                         {"period": 0.25, "rate_hz": 4.0, "silent": float("nan")},
                                         "period 0.25 s fits degraded, warm")])
    rec.on_observations(T0 + 60, [Observation(T0 + 60, "hz", CAM, Code.GENERAL_OK, degraded,
                                              {"period": 0.5}, "not stored in a sample")])
    rec.on_observations(T0 + 61, [Observation(T0 + 61, "hz", CAM, Code.TIMEOUT)])
    rec.close()
    change, sample, fault = entries(tmp_path / "log.db", entity=CAM.topic)
    assert (change.kind, change.code, change.characteristic) == ("observation", 0, "hz")
    assert change.payload == {"values": {"period": 0.25, "rate_hz": 4.0, "silent": "nan"},
                              "states": [2, 5], "state_names": ["degraded", "warm"],
                              "code_name": "GENERAL_OK",
                              "message": "period 0.25 s fits degraded, warm"}
    assert (sample.kind, sample.payload) == ("sample", {"values": {"period": 0.5},
                                                        "states": [2, 5]})
    assert (fault.kind, fault.code) == ("exceedance", -4)
    event_id = EventId.parse(fault.payload.pop("event_id"))
    assert event_id is not None and event_id.sequence == 1  # a fault's onset is an event
    assert fault.payload == {"values": {}, "states": [], "state_names": [],
                             "code_name": "TIMEOUT"}


def test_an_observation_that_cannot_be_encoded_is_logged_as_such_and_writing_goes_on(
        tmp_path: Path) -> None:
    events: list[BlackBoxEvent] = []
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=0.05, snapshot=None),
                   robot_id="r1", on_self_event=events.append)
    bad = Observation(T0, "hz", CAM, Code.GENERAL_OK, OK, {("not", "a", "key"): 1.0},  # type: ignore[dict-item]
                      "odd values")
    rec.on_observations(T0, [bad, obs(T0, resource=Resource(topic="/t"))])
    rec.close()
    logged = entries(tmp_path / "log.db", kinds=["observation"])
    assert [e.entity for e in logged] == [CAM.topic, "/t"]
    assert logged[0].payload["message"] == "odd values"
    assert logged[0].payload["unencodable"].startswith("TypeError: keys must be")
    assert logged[1].payload["values"] == {"period": 0.0667}
    assert events == [] and rec.health().code == Code.GENERAL_OK


def test_a_full_batch_is_committed_before_the_commit_interval_ends(tmp_path: Path) -> None:
    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=3600.0, commit_rows=100,
                                    snapshot=None),
                   robot_id="r1")
    # The start event and 150 changes: more than commit_rows, so the writer goes at once.
    rec.on_observations(T0, [obs(T0, resource=Resource(topic=f"/t{k}")) for k in range(150)])
    wait_for(lambda: rec.written == 151)
    rec.on_observations(T0 + 1, [obs(T0 + 1, resource=Resource(topic="/late"))])
    assert rec.written == 151  # one row is no batch: it waits for the interval (or close)
    rec.close()
    assert rec.written == 153  # ... and the stop event
    assert len(entries(tmp_path / "log.db", kinds=["observation"])) == 151
