"""Replaying recordings: ROS 1 bags, rosbag2 (sqlite3 and MCAP storage) and MCAP files feed
the same events, observers and diagnosis as a live robot, on the recorded clock."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from blackbox.app import RunOptions, build
from blackbox.config.node import ConfigError
from blackbox.events import GraphSnapshot, Interest, MessageArrival
from blackbox.model import BlackBoxEvent, Code, Resource
from blackbox.output.jsonlines import read_records
from blackbox.pipeline import Pipeline
from blackbox.record.snapshot import Held, write_bag, write_mcap
from blackbox.sinks import SinkBase
from blackbox.sources import open_source
from blackbox.sources.bag import BagSource, placeholder_publisher
from blackbox.sources.base import SourceOptions
from blackbox.sources.sim import Fault, SimulatedSource, Topology

pytestmark = pytest.mark.xdist_group("test_bag_source")  # its module fixture: one worker

T0 = 1_700_000_000.0  # recordings carry epoch times
SMALL = frozenset({"/audio", "/signal"})


def simulated_run(seconds: float, topics: frozenset[str] = SMALL,
                  faults: list[Fault] | None = None) -> tuple[list[Held], SimulatedSource]:
    """The thesis robot's raw messages, as the recorder's ring buffer holds them."""
    robot = Topology.thesis()
    source = SimulatedSource(robot, faults or [], seed=3, start_time=T0)
    source.start(Interest(topics=topics))
    held = [Held(e.time, e.topic, e.publisher, e.raw() or b"")
            for e in source.poll(T0 + seconds) if isinstance(e, MessageArrival)]
    return held, source


def replay(path: Path, interest: Interest, until: float = T0 + 3600) -> list[object]:
    source = BagSource(path)
    source.start(interest)
    events: list[object] = source.poll(until)
    assert source.exhausted()
    return events


def arrivals(events: list[object]) -> list[MessageArrival]:
    return [e for e in events if isinstance(e, MessageArrival)]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Held], Path, Path]:
    """Ten seconds of /audio and /signal, in the recorder's two snapshot formats."""
    held, source = simulated_run(10.0)
    schemas = {t: source.schema(t) for t in SMALL}
    root = tmp_path_factory.mktemp("bags")
    write_bag(held, schemas, root / "run.bag")
    write_mcap(held, schemas, root / "run.mcap")
    return held, root / "run.bag", root / "run.mcap"


def test_a_ros1_bag_replays_every_message_at_its_recorded_time_from_its_recorded_publisher(
        recorded: tuple[list[Held], Path, Path]) -> None:
    held, bag, _ = recorded
    got = arrivals(replay(bag, Interest(topics=SMALL)))
    assert [(m.topic, m.publisher, len(m.raw() or b"")) for m in got] == \
        [(h.topic, h.publisher, len(h.data)) for h in held]
    assert all(abs(m.time - h.time) < 1e-6 for m, h in zip(got, held, strict=True))
    assert [m.raw() for m in got] == [bytes(h.data) for h in held]
    assert [m.size for m in got] == [len(h.data) for h in held]


def test_values_are_decoded_only_for_topics_a_value_observer_needs(
        recorded: tuple[list[Held], Path, Path]) -> None:
    _, bag, _ = recorded
    got = arrivals(replay(bag, Interest(topics=SMALL, decoded=frozenset({"/signal"}))))
    signal = [m.value for m in got if m.topic == "/signal"]
    assert len(signal) > 100 and all(14.4 < v.data < 15.6 for v in signal)
    assert all(m.value is None for m in got if m.topic == "/audio")


def test_the_graph_names_recorded_topics_types_and_publishers(
        recorded: tuple[list[Held], Path, Path]) -> None:
    _, bag, mcap = recorded
    graphs = [e for e in replay(bag, Interest(topics=SMALL)) if isinstance(e, GraphSnapshot)]
    last = graphs[-1]
    assert {t: (i.type, i.publishers) for t, i in last.topics.items()} == {
        "/audio": ("audio_common_msgs/AudioData", ("/audio_capture",)),
        "/signal": ("std_msgs/Float64", ("/Signal_generator",))}
    assert last.nodes == {}  # a bag records no liveness
    # The recorder's MCAP snapshots keep no publisher: each topic gets its placeholder.
    got = arrivals(replay(mcap, Interest(topics=SMALL)))
    assert {m.publisher for m in got if m.topic == "/signal"} == {
        placeholder_publisher("/signal")} == {"(publisher of /signal)"}


def test_the_recorders_mcap_snapshot_replays_the_same_messages(
        recorded: tuple[list[Held], Path, Path]) -> None:
    _, bag, mcap = recorded
    from_bag = arrivals(replay(bag, Interest(topics=SMALL, decoded=SMALL)))
    from_mcap = arrivals(replay(mcap, Interest(topics=SMALL, decoded=SMALL)))
    assert [(m.time, m.topic, m.raw()) for m in from_mcap] == \
        [(m.time, m.topic, m.raw()) for m in from_bag]
    assert [m.value.data for m in from_mcap if m.topic == "/signal"] == \
        [m.value.data for m in from_bag if m.topic == "/signal"]


def test_only_topics_of_interest_are_delivered(recorded: tuple[list[Held], Path, Path]) -> None:
    _, bag, _ = recorded
    got = arrivals(replay(bag, Interest(topics=frozenset({"/signal"}))))
    assert got and {m.topic for m in got} == {"/signal"}


def ros2_bag(path: Path, storage: StoragePlugin) -> list[tuple[int, float]]:
    """A rosbag2 with /value (std_msgs/msg/Float64, 10 Hz, 3 s) in CDR."""
    store = get_typestore(Stores.LATEST)
    float64 = store.types["std_msgs/msg/Float64"]
    written = []
    with Ros2Writer(path, version=9, storage_plugin=storage) as writer:
        conn = writer.add_connection("/value", "std_msgs/msg/Float64", typestore=store)
        for i in range(30):
            stamp = int((T0 + 0.1 * i) * 1e9)
            writer.write(conn, stamp, store.serialize_cdr(float64(data=float(i)), conn.msgtype))
            written.append((stamp, float(i)))
    return written


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_rosbag2_directories_replay_with_values_decoded_from_cdr(
        tmp_path: Path, storage: StoragePlugin) -> None:
    written = ros2_bag(tmp_path / "rosbag2", storage)
    events = replay(tmp_path / "rosbag2", Interest(decoded=frozenset({"/value"})))
    got = arrivals(events)
    assert [(round(m.time * 1e9), m.value.data) for m in got] == \
        [(s, v) for s, v in written]
    assert {m.publisher for m in got} == {"(publisher of /value)"}
    graph = next(e for e in events if isinstance(e, GraphSnapshot))
    assert graph.topics["/value"].type == "std_msgs/msg/Float64"


def test_a_plain_mcap_file_with_ros2_cdr_messages_replays(tmp_path: Path) -> None:
    written = ros2_bag(tmp_path / "rosbag2", StoragePlugin.MCAP)
    (mcap,) = (tmp_path / "rosbag2").glob("*.mcap")
    plain = tmp_path / "plain.mcap"
    plain.write_bytes(mcap.read_bytes())
    got = arrivals(replay(plain, Interest(decoded=frozenset({"/value"}))))
    assert [m.value.data for m in got] == [v for _, v in written]


def truncated_copy(src: Path, dst: Path, fraction: float) -> int:
    data = src.read_bytes()
    cut = int(len(data) * fraction)
    dst.write_bytes(data[:cut])
    return cut


@pytest.mark.parametrize("kind", ["bag", "mcap"])
def test_a_truncated_file_replays_everything_before_the_damage_and_names_its_offset(
        recorded: tuple[list[Held], Path, Path], tmp_path: Path, kind: str) -> None:
    held, bag, mcap = recorded
    src = bag if kind == "bag" else mcap
    cut = truncated_copy(src, tmp_path / f"cut.{kind}", 0.6)
    source = BagSource(tmp_path / f"cut.{kind}")
    source.start(Interest(topics=SMALL))
    events = source.poll(T0 + 3600)
    assert source.exhausted()
    got = arrivals(events)
    damage = [e for e in events if isinstance(e, BlackBoxEvent) and e.kind == "bag_corrupt"]
    assert len(damage) == 1 and events[-1] is damage[0]
    assert source.corruption is not None
    offset = source.corruption.offset
    assert offset is not None and 0 < offset <= cut
    assert f"at byte {offset:,}" in damage[0].message
    assert f"the {len(got):,} messages before it were replayed" in damage[0].message
    # Everything before the damage: a prefix of the recording, ending near the cut.
    assert [(m.topic, m.raw()) for m in got] == \
        [(h.topic, bytes(h.data)) for h in held[:len(got)]]
    assert len(got) >= 0.4 * len(held)


def test_a_damaged_record_header_inside_a_bag_is_reported_at_its_chunk(
        recorded: tuple[list[Held], Path, Path], tmp_path: Path) -> None:
    held, bag, _ = recorded
    data = bytearray(bag.read_bytes())
    op_field = b"\x04\x00\x00\x00op=\x02"  # the 'op' field of a message record header
    places = [i for i in range(len(data)) if data.startswith(op_field, i)]
    hit = places[len(places) // 2]
    data[hit:hit + 4] = b"\xff\xff\x00\x00"  # a field length running past its header
    damaged = tmp_path / "damaged.bag"
    damaged.write_bytes(bytes(data))
    source = BagSource(damaged)
    source.start(Interest(topics=SMALL))
    got = arrivals(source.poll(T0 + 3600))
    assert source.corruption is not None
    assert source.corruption.offset is not None and source.corruption.offset < hit
    assert "bad record header" in str(source.corruption) or "overruns" in str(source.corruption)
    assert len(got) == len(places) // 2  # every message before the damaged one
    assert [m.raw() for m in got] == [bytes(h.data) for h in held[:len(got)]]


def test_a_file_that_is_no_recording_is_a_clear_config_error(tmp_path: Path) -> None:
    junk = tmp_path / "notes.txt"
    junk.write_text("hello")
    with pytest.raises(ConfigError, match="neither a ROS 1 bag, an MCAP file nor a rosbag2"):
        open_source(f"bag:{junk}")
    with pytest.raises(ConfigError, match="no such file"):
        open_source(f"bag:{tmp_path / 'missing.bag'}")
    with pytest.raises(ConfigError, match=r"without metadata\.yaml"):
        open_source(f"bag:{tmp_path}")


def unknown_type_bag(path: Path) -> None:
    """/secret of a type with no definition anywhere, 20 Hz for 5 s, next to /signal."""
    store = get_typestore(Stores.ROS1_NOETIC)
    float64 = store.types["std_msgs/msg/Float64"]
    with Ros1Writer(path) as writer:
        secret = writer.add_connection("/secret", "acme_msgs/msg/Secret", msgdef="",
                                       md5sum="0123456789abcdef0123456789abcdef",
                                       callerid="/vault")
        signal = writer.add_connection("/signal", "std_msgs/msg/Float64", typestore=store,
                                       callerid="/Signal_generator")
        for i in range(100):
            t = int((T0 + 0.05 * i) * 1e9)
            writer.write(secret, t, b"\x01\x02\x03\x04")
            writer.write(signal, t + 1000,
                         store.serialize_ros1(float64(data=15.0), "std_msgs/msg/Float64"))


UNKNOWN_CONFIG = """
version: 1
robot: {id: vault}
observers:
  - type: hz
    topic: /secret
    filter: {type: mean, window_size: 10}
    states:
      - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.05, std_deviation: 0.01}}}
  - type: scores
    topic: /secret
    field: data
    filter: {type: mean, window_size: 10}
    states:
      - {number: 1, name: ok, score: {value: {type: gauss, mean: 1.0, std_deviation: 0.5}}}
  - type: scores
    topic: /signal
    field: data
    filter: {type: mean, window_size: 10}
    states:
      - {number: 1, name: ok, score: {value: {type: gauss, mean: 15.0, std_deviation: 0.5}}}
diagnosis: {enabled: false}
"""


SIGNAL_CONFIG = """
version: 1
robot: {id: thesis-robot}
observers:
  - type: scores
    topic: /signal
    field: data
    filter: {type: mean, window_size: 10}
    states:
      - {number: 1, name: ok, score: {value: {type: gauss, mean: 15.0, std_deviation: 0.5}}}
"""


class Collect(SinkBase):
    def __init__(self) -> None:
        self.observations: list = []
        self.events: list[BlackBoxEvent] = []

    def on_observations(self, now: float, observations: list) -> None:  # type: ignore[override]
        self.observations.extend(observations)

    def on_event(self, event: BlackBoxEvent) -> None:
        self.events.append(event)


def test_an_unknown_type_is_reported_once_per_topic_and_its_rate_still_observed(
        tmp_path: Path) -> None:
    unknown_type_bag(tmp_path / "vault.bag")
    config = tmp_path / "vault.yaml"
    config.write_text(UNKNOWN_CONFIG)
    sink = Collect()
    box = build(RunOptions(config=config, source=f"bag:{tmp_path / 'vault.bag'}",
                           simulated_clock=True, live=False, extra_sinks=[sink]))
    box.run()
    reports = [e for e in sink.events if e.kind == "bag_unknown_type"]
    assert [(e.component, "acme_msgs/Secret" in e.message) for e in reports] == \
        [("/secret", True)]
    rate = [o for o in sink.observations
            if o.observer == "hz" and o.resource.topic == "/secret"]
    assert rate and rate[-1].code == Code.GENERAL_OK
    assert abs(rate[-1].values["period"] - 0.05) < 1e-6
    secret_values = [o for o in sink.observations
                     if o.observer == "scores" and o.resource.topic == "/secret"]
    assert secret_values and all(o.code < 0 for o in secret_values)
    signal = [o for o in sink.observations
              if o.observer == "scores" and o.resource == Resource(topic="/signal")]
    assert signal and signal[-1].code == Code.GENERAL_OK


def test_real_time_replay_waits_for_the_wall_clock_scaled_by_the_rate(
        recorded: tuple[list[Held], Path, Path]) -> None:
    _, bag, _ = recorded
    source = open_source(f"bag:{bag}", SourceOptions(realtime=True, rate=4.0))
    source.start(Interest(topics=SMALL))
    begin = source.now()
    wall = time.monotonic()
    events = source.poll(begin + 2.0)  # two recorded seconds at 4x: at least 0.5 s
    elapsed = time.monotonic() - wall
    assert elapsed >= 0.5 * 0.99
    assert arrivals(events) and all(e.time <= begin + 2.0 for e in arrivals(events))
    source.close()


def test_rate_is_refused_for_live_sources_and_with_a_simulated_clock(
        recorded: tuple[list[Held], Path, Path]) -> None:
    _, bag, _ = recorded
    with pytest.raises(ConfigError, match="not a recording"):
        open_source("sim:thesis", SourceOptions(realtime=True, rate=2.0))
    with pytest.raises(ConfigError, match="cannot go with --simulated-clock"):
        open_source(f"bag:{bag}", SourceOptions(realtime=False, rate=2.0))


def test_a_replay_run_ends_by_itself_when_the_recording_runs_out(
        recorded: tuple[list[Held], Path, Path], tmp_path: Path) -> None:
    _, bag, _ = recorded
    source = open_source(f"bag:{bag}", SourceOptions(realtime=False))
    pipeline = Pipeline(source, [])
    stats = pipeline.run()
    assert stats.messages == 0  # nobody asked for a topic
    assert 9.0 < stats.ended - stats.started < 11.0


def test_the_cli_replays_a_bag_and_writes_observations_on_the_recorded_clock(
        recorded: tuple[list[Held], Path, Path], tmp_path: Path) -> None:
    _, bag, _ = recorded
    out = tmp_path / "obs.jsonl"
    config = tmp_path / "signal.yaml"
    config.write_text(SIGNAL_CONFIG)
    run = subprocess.run([sys.executable, "-m", "blackbox", "run", "--config", str(config),
                          "--source", f"bag:{bag}", "--simulated-clock", "--quiet",
                          "--observations", str(out)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    records = list(read_records(out))
    times = [r["time"] for r in records]
    assert records and min(times) > T0 and max(times) < T0 + 12
    assert {r["observer"] for r in records} == {"scores"}
    assert records[-1]["code_name"] == "GENERAL_OK"
    truncated_copy(bag, tmp_path / "cut.bag", 0.5)
    cut = subprocess.run([sys.executable, "-m", "blackbox", "run", "--config", str(config),
                          "--source", f"bag:{tmp_path / 'cut.bag'}", "--simulated-clock",
                          "--quiet"], capture_output=True, text=True, timeout=120)
    assert cut.returncode == 0 and "cut.bag: corrupt or truncated at byte " in cut.stderr
    assert "messages before it are replayed" in cut.stderr
    bad = subprocess.run([sys.executable, "-m", "blackbox", "run", "--source",
                          "sim:thesis", "--rate", "2", "--quiet", "--duration", "1"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "not a recording" in bad.stderr


def test_a_snapshot_the_recorder_took_during_a_fault_replays_with_the_fault_in_it(
        tmp_path: Path) -> None:
    faults = tmp_path / "faults.yaml"
    faults.write_text("faults:\n  - {kind: offset, component: /signal, start: 10, end: 20, "
                      "value: 5}\n")
    build(RunOptions(source="sim:thesis", simulated_clock=True, duration=30.0,
                     faults=str(faults), record=tmp_path / "bb.db", live=False)).run()
    (snapshot,) = (tmp_path / "bb.db.snapshots").iterdir()
    config = tmp_path / "signal.yaml"
    config.write_text(SIGNAL_CONFIG)
    sink = Collect()
    build(RunOptions(config=config, source=f"bag:{snapshot}", simulated_clock=True,
                     live=False, extra_sinks=[sink])).run()
    scores = [(o.time, o.code) for o in sink.observations if o.observer == "scores"]
    assert any(code == Code.GENERAL_OK for t, code in scores if t < 10.0)
    assert any(code < 0 for t, code in scores if t > 11.0)
    assert not [e for e in sink.events if e.kind.startswith("bag_")]


@pytest.mark.parametrize("fmt", [Ros1Writer.CompressionFormat.BZ2,
                                 Ros1Writer.CompressionFormat.LZ4])
def test_compressed_bags_replay_whole_and_cut_off(
        recorded: tuple[list[Held], Path, Path], tmp_path: Path,
        fmt: Ros1Writer.CompressionFormat) -> None:
    held, _, _ = recorded
    path = tmp_path / "compressed.bag"
    writer = Ros1Writer(path)
    writer.set_compression(fmt)
    writer.chunk_threshold = 16 * 1024  # several chunks
    store = get_typestore(Stores.ROS1_NOETIC)
    with writer:
        # /audio is read for timing only here, so any type serves as its connection's.
        audio = writer.add_connection("/audio", "std_msgs/msg/UInt8MultiArray",
                                      typestore=store, callerid="/audio_capture")
        signal = writer.add_connection("/signal", "std_msgs/msg/Float64", typestore=store,
                                       callerid="/Signal_generator")
        for h in held:
            writer.write(signal if h.topic == "/signal" else audio, int(h.time * 1e9),
                         bytes(h.data))
    whole = arrivals(replay(path, Interest(topics=SMALL, decoded=frozenset({"/signal"}))))
    assert [m.raw() for m in whole] == [bytes(h.data) for h in held]
    assert all(14 < m.value.data < 16 for m in whole if m.topic == "/signal")
    cut = tmp_path / "cut.bag"
    truncated_copy(path, cut, 0.5)
    source = BagSource(cut)
    source.start(Interest(topics=SMALL))
    part = arrivals(source.poll(T0 + 3600))
    # Whole chunks before the cut replay; a compressed chunk's blocks only once complete.
    assert source.corruption is not None and 0.3 * len(held) < len(part) < len(held)
    assert [m.raw() for m in part] == [bytes(h.data) for h in held[:len(part)]]
