"""The simulated thesis robot as a Source: rates, sizes, values, bytes, clock."""

from __future__ import annotations

import itertools
import statistics
import tracemalloc
from pathlib import Path

import pytest
from rosbags.rosbag1 import Reader, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from blackbox.events import GraphSnapshot, Interest, MessageArrival, NetworkSample, ResourceSample
from blackbox.sources.sim import SimulatedSource, Topology, open_sim
from blackbox.sources.sim.topology import THESIS_FILE

pytestmark = pytest.mark.xdist_group("test_sim_robot")  # its module fixture: one worker

THESIS = Topology.thesis()
EVERYTHING = Interest(topics=frozenset(THESIS.topics), decoded=frozenset({"/signal"}),
                      resources=frozenset(THESIS.nodes), network=True)


def run(source: SimulatedSource, seconds: float, interest: Interest = EVERYTHING,
        step: float = 1.0) -> list:
    source.start(interest)
    events = []
    t = source.start_time
    while t < source.start_time + seconds:
        t = min(t + step, source.start_time + seconds)
        events += source.poll(t)
    return events


def arrivals(events: list, topic: str) -> list[MessageArrival]:
    return [e for e in events if isinstance(e, MessageArrival) and e.topic == topic]


@pytest.fixture(scope="module")
def minute() -> list:
    return run(SimulatedSource(THESIS, seed=1), 60.0)


@pytest.mark.parametrize(("topic", "rate"), [("/usb_cam/image_raw", 15.0),
                                             ("/audio", 33.333), ("/signal", 15.0)])
def test_rates_over_a_minute_stay_inside_the_thesis_hz_threshold(minute, topic, rate):
    times = [a.time for a in arrivals(minute, topic)]
    assert abs(len(times) - 60 * rate) <= 2
    periods = [b - a for a, b in itertools.pairwise(times)]
    # the thesis hz observer: mean of 50 periods, gauss with std 0.01 s around 1 / rate
    windows = [statistics.fmean(periods[i:i + 50]) for i in range(len(periods) - 49)]
    assert max(abs(w - 1 / rate) for w in windows) < 0.002


def test_signal_values_are_15_plus_minus_half(minute):
    values = [a.value.data for a in arrivals(minute, "/signal")]
    assert all(14.5 <= v <= 15.5 for v in values)
    windows = [statistics.fmean(values[i:i + 50]) for i in range(len(values) - 49)]
    assert all(abs(w - 15.0) < 0.5 for w in windows)
    assert statistics.pstdev(values) > 0.2  # uniform +-0.5 has std 0.29: it is noisy


def test_message_sizes(minute):
    # image: header (seq 4, stamp 8, frame_id 4 + 7) + height, width 8 + encoding 4 + 4
    # + is_bigendian 1 + step 4 + data length 4 + 640 * 480 * 3
    assert {a.size for a in arrivals(minute, "/usb_cam/image_raw")} == {921_600 + 48}
    assert {a.size for a in arrivals(minute, "/audio")} == {480 + 4}
    assert {a.size for a in arrivals(minute, "/signal")} == {8}


def test_decoded_values_look_like_rosbags_messages(minute):
    image = arrivals(minute, "/usb_cam/image_raw")[10]
    msg = image.value
    assert (msg.height, msg.width, msg.encoding, msg.step) == (480, 640, "rgb8", 1920)
    assert msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 == pytest.approx(image.time)
    assert msg.header.frame_id == "usb_cam"
    assert msg.header.seq == 11
    assert len(msg.data) == 921_600
    assert len(arrivals(minute, "/audio")[0].value.data) == 480


def test_raw_bytes_decode_with_the_published_definition(minute):
    """A consumer that knows only the schema (as from a TCPROS header) can read the bytes."""
    source = SimulatedSource(THESIS)
    for topic in THESIS.topics:
        schema = source.schema(topic)
        assert schema.encoding == "ros1"
        store = get_typestore(Stores.EMPTY)
        pkg, name = schema.type.split("/")
        store.register(get_types_from_msg(schema.definition, f"{pkg}/msg/{name}"))
        arrival = arrivals(minute, topic)[3]
        raw = arrival.raw()
        assert len(raw) == arrival.size
        decoded = store.deserialize_ros1(raw, f"{pkg}/msg/{name}")
        if topic == "/signal":
            assert decoded.data == arrival.value.data
        if topic == "/usb_cam/image_raw":
            assert decoded.header.stamp.sec == arrival.value.header.stamp.sec
            assert bytes(decoded.data) == bytes(arrival.value.data)


def test_schema_is_the_ros1_definition():
    schema = SimulatedSource(THESIS).schema("/usb_cam/image_raw")
    assert schema.type == "sensor_msgs/Image"
    assert schema.definition.startswith("std_msgs/Header header\n")
    assert schema.md5sum == "060021388200f6f0f447d0fcd9c64743"  # sensor_msgs/Image in ROS 1
    assert SimulatedSource(THESIS).schema("/nope") is None


def test_bags_written_from_raw_bytes_are_valid(minute, tmp_path: Path):
    source = SimulatedSource(THESIS)
    bag = tmp_path / "sim.bag"
    with Writer(bag) as writer:
        conns = {}
        for topic in ("/signal", "/audio"):
            s = source.schema(topic)
            conns[topic] = writer.add_connection(topic, s.type.replace("/", "/msg/"),
                                                 msgdef=s.definition, md5sum=s.md5sum)
        for a in minute:
            if isinstance(a, MessageArrival) and a.topic in conns:
                writer.write(conns[a.topic], int(a.time * 1e9) + 1, a.raw())
    with Reader(bag) as reader:
        assert reader.message_count == len(arrivals(minute, "/signal")) + len(
            arrivals(minute, "/audio"))
        store = get_typestore(Stores.ROS1_NOETIC)
        conn, _, raw = next(reader.messages(connections=[
            c for c in reader.connections if c.topic == "/signal"]))
        assert conn.msgtype == "std_msgs/msg/Float64"
        assert store.deserialize_ros1(raw, conn.msgtype).data == arrivals(
            minute, "/signal")[0].value.data


def test_image_payloads_are_not_allocated_per_message():
    tracemalloc.start()
    try:
        events = run(SimulatedSource(THESIS), 20.0,
                     Interest(topics=frozenset(THESIS.topics)))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(arrivals(events, "/usb_cam/image_raw")) >= 299  # 300 images = 276 MB if real
    assert peak < 20_000_000


def test_graph_snapshot_every_second(minute):
    graphs = [e for e in minute if isinstance(e, GraphSnapshot)]
    assert [g.time for g in graphs] == [float(k) for k in range(61)]
    g = graphs[5]
    assert {n: (i.alive, i.pid) for n, i in g.nodes.items()} == {
        "/usb_cam": (True, 2101), "/audio_capture": (True, 2102), "/Signal_generator": (True, 2103)}
    assert g.topics["/audio"].publishers == ("/audio_capture",)
    assert g.topics["/audio"].subscribers == ("/Signal_generator",)
    assert g.topics["/audio"].type == "audio_common_msgs/AudioData"


def test_resource_samples_per_node_at_1_hz(minute):
    cam = [e for e in minute if isinstance(e, ResourceSample) and e.node == "/usb_cam"]
    assert [s.time for s in cam] == [float(k) for k in range(61)]
    assert all(12.5 <= s.cpu_percent <= 15.5 for s in cam)
    assert all(40_850_000 <= s.memory_bytes <= 41_150_000 for s in cam)


def test_only_interesting_nodes_and_topics_are_reported():
    events = run(SimulatedSource(THESIS), 5.0,
                 Interest(topics=frozenset({"/audio"}), resources=frozenset({"/usb_cam"})))
    assert {e.topic for e in events if isinstance(e, MessageArrival)} == {"/audio"}
    assert {e.node for e in events if isinstance(e, ResourceSample)} == {"/usb_cam"}
    assert not [e for e in events if isinstance(e, NetworkSample)]


def test_network_counts_every_published_byte(minute):
    samples = [e for e in minute if isinstance(e, NetworkSample)]
    assert {s.interface for s in samples} == {"eth0"}
    messages = [e for e in minute if isinstance(e, MessageArrival)]
    for s in samples:
        assert s.tx_bytes == sum(m.size for m in messages if m.time < s.time)
        # /signal has no subscriber; the two inputs have one each
        assert s.rx_bytes == sum(m.size for m in messages
                                 if m.time < s.time and m.topic != "/signal")
    per_second = samples[-1].tx_bytes - samples[-2].tx_bytes
    assert 13_800_000 < per_second < 13_900_000  # 15 x 921,648 + 33 x 484 + 15 x 8


def test_poll_returns_each_event_once_in_time_order():
    source = SimulatedSource(THESIS, seed=3)
    events = run(source, 10.0, EVERYTHING, step=0.37)
    times = [e.time for e in events]
    assert times == sorted(times)
    assert len({id(e) for e in events}) == len(events)
    assert source.now() == 10.0
    assert source.poll(5.0) == []
    assert all(e.time <= 10.5 for e in source.poll(10.5))


def test_same_seed_same_robot_other_seed_other_robot():
    def trace(seed: int) -> list:
        return [(type(e).__name__, e.time, getattr(e, "topic", ""),
                 e.value.data if getattr(e, "topic", "") == "/signal" else None,
                 getattr(e, "cpu_percent", None))
                for e in run(SimulatedSource(THESIS, seed=seed), 10.0)]

    assert trace(7) == trace(7)
    assert trace(7) != trace(8)


def test_start_time_offsets_the_clock_and_stamps():
    events = run(SimulatedSource(THESIS, start_time=1_700_000_000.0), 3.0)
    signal = arrivals(events, "/signal")
    assert 1_700_000_000.0 < signal[0].time < 1_700_000_000.1
    assert signal[0].value is not None
    assert all(1_700_000_000.0 <= e.time <= 1_700_000_003.0 for e in events)


def test_lifecycle_errors():
    source = SimulatedSource(THESIS)
    with pytest.raises(RuntimeError, match="start"):
        source.poll(1.0)
    source.start(EVERYTHING)
    with pytest.raises(RuntimeError, match="already started"):
        source.start(EVERYTHING)
    with pytest.raises(ValueError, match="finite"):
        source.poll(float("inf"))  # the robot never runs out of events
    source.close()
    assert source.poll(5.0) == []
    with pytest.raises(ValueError, match="start_time"):
        SimulatedSource(THESIS, start_time=-1.0)


def test_five_simulated_minutes_of_the_thesis_robot():
    events = run(SimulatedSource(THESIS), 300.0)
    assert abs(len(arrivals(events, "/usb_cam/image_raw")) - 4500) <= 2
    assert abs(len(arrivals(events, "/audio")) - 10_000) <= 3


def test_realtime_poll_returns_only_after_the_wall_clock_passed():
    source = SimulatedSource(THESIS, realtime=True)
    source.start(EVERYTHING)
    collected = []
    for until in (0.1, 0.2, 0.3):
        events = source.poll(until)
        now = source.now()
        assert now >= until
        assert all(e.time <= until <= now for e in events)
        collected += events
    assert len(arrivals(collected, "/signal")) >= 3


def test_open_sim_uris(tmp_path: Path):
    assert open_sim("sim:thesis").name == "sim:thesis"
    assert open_sim("sim:thesis").topology == THESIS
    path = tmp_path / "robot.yaml"
    path.write_text(THESIS_FILE.read_text().replace("name: thesis", "name: mine"))
    source = open_sim(f"sim:{path}?seed=4&realtime=1")
    assert (source.name, source.seed, source.realtime) == ("sim:mine", 4, True)
    assert open_sim(f"sim:{path}?seed=4", seed=9).seed == 9
    with pytest.raises(ValueError, match="unknown built-in robot 'thesi'"):
        open_sim("sim:thesi")
    with pytest.raises(ValueError, match="unknown option"):
        open_sim("sim:thesis?speed=2")


def test_any_noetic_type_with_a_nested_numeric_field():
    robot = Topology.parse("""\
nodes: [{name: /base}]
topics:
  - {name: /cmd_vel, type: geometry_msgs/Twist, publisher: /base, rate: 10,
     value: {field: linear.x, mean: 0.5, noise: 0.1, distribution: gauss}}
  - {name: /ticks, type: std_msgs/Int32, publisher: /base, rate: 10,
     value: {field: data, mean: 7, noise: 0.4}}
""")
    events = run(SimulatedSource(robot, seed=2), 5.0, Interest(topics=frozenset(robot.topics)))
    twists = arrivals(events, "/cmd_vel")
    assert {a.size for a in twists} == {48}  # six float64
    xs = [a.value.linear.x for a in twists]
    assert 0.3 < statistics.fmean(xs) < 0.7
    assert {a.value.angular.z for a in twists} == {0.0}
    store = get_typestore(Stores.ROS1_NOETIC)
    assert store.deserialize_ros1(twists[0].raw(), "geometry_msgs/msg/Twist").linear.x == xs[0]
    # integer fields are rounded: 7 +- 0.4 is always 7
    assert {a.value.data for a in arrivals(events, "/ticks")} == {7}
