"""The flight recorder: a bounded ring buffer of raw messages, written as bag or MCAP."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
from pathlib import Path

import pytest

from blackbox.events import MessageArrival, TopicSchema
from blackbox.record.snapshot import RingBuffer, SnapshotConfig, write_bag, write_mcap

STRING = TopicSchema("/chatter", "std_msgs/String", "ros1", "string data",
                     "992ce8a1687cec8c8bd883ec73ca41d1")
T0 = 1_700_000_000.0


def ros1_string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def arrival(t: float, topic: str, data: bytes, publisher: str = "/talker") -> MessageArrival:
    return MessageArrival(t, topic, publisher, len(data), raw=lambda: data)


def test_ring_keeps_only_the_last_seconds() -> None:
    ring = RingBuffer(SnapshotConfig(before=2.0, max_bytes=10_000))
    for i in range(10):
        ring.offer(arrival(T0 + i * 0.5, "/chatter", b"x" * 10))
    # newest at +4.5 s: everything from +2.5 s on stays (2.5, 3.0, 3.5, 4.0, 4.5)
    assert len(ring) == 5
    assert ring.bytes == 50


def test_ring_never_holds_more_than_its_byte_cap() -> None:
    ring = RingBuffer(SnapshotConfig(before=100.0, max_bytes=1000))
    for i in range(50):
        ring.offer(arrival(T0 + i, "/image", b"i" * 300))
        assert ring.bytes <= 1000
    assert len(ring) == 3
    ring.offer(arrival(T0 + 51, "/image", b"i" * 1001))  # bigger than the whole cap
    assert ring.skipped_oversize == 1
    assert len(ring) == 3


def test_ring_keeps_the_same_bytes_object_without_copying() -> None:
    ring = RingBuffer(SnapshotConfig())
    data = b"payload" * 100
    ring.offer(arrival(T0, "/chatter", data))
    capture = ring.trigger(T0, "x.bag")
    assert capture.messages[0].data is data


def test_include_exclude_and_keep_one_of_n() -> None:
    ring = RingBuffer(SnapshotConfig(include=("/cam/*", "/chatter"), exclude=("/cam/debug",),
                                     keep_one_of={"/cam/image*": 3}))
    for i in range(9):
        for topic in ("/cam/image_raw", "/cam/debug", "/chatter", "/other"):
            ring.offer(arrival(T0 + i * 0.1, topic, b"m"))
    capture = ring.trigger(T0 + 1.0, "x.bag")
    topics = [h.topic for h in capture.messages]
    assert topics.count("/cam/image_raw") == 3  # messages 0, 3 and 6 of nine
    assert topics.count("/chatter") == 9
    assert "/cam/debug" not in topics and "/other" not in topics


def test_capture_holds_seconds_before_and_after_the_trigger() -> None:
    ring = RingBuffer(SnapshotConfig(before=1.0, after=2.0))
    for i in range(50):  # 10 Hz for 5 s
        ring.offer(arrival(T0 + i * 0.1, "/chatter", ros1_string(str(i))))
        if i == 20:
            capture = ring.trigger(T0 + 2.0, "x.bag")
            assert ring.trigger(T0 + 2.5, "y.bag") is capture  # joins the running one
    assert ring.complete(T0 + 3.9) == []
    (done,) = ring.complete(T0 + 4.0)
    times = [round(h.time - T0, 1) for h in done.messages]
    assert times[0] == 1.0 and times[-1] == 4.0 and len(times) == 31


def test_capture_is_bounded_too() -> None:
    ring = RingBuffer(SnapshotConfig(before=0.0, after=10.0, max_bytes=100))
    capture = ring.trigger(T0, "x.bag")
    for i in range(20):
        ring.offer(arrival(T0 + i * 0.1, "/chatter", b"z" * 10))
    assert capture.size == 100 and capture.dropped == 10


def _messages(n: int) -> list:
    ring = RingBuffer(SnapshotConfig(before=60.0))
    for i in range(n):
        ring.offer(arrival(T0 + i * 0.1, "/chatter", ros1_string(f"hello {i}")))
        ring.offer(arrival(T0 + i * 0.1, "/sim/pose", b'{"x": %d}' % i, "/sim"))
    return ring.trigger(T0 + n * 0.1, "x").messages


def test_bag_is_read_back_by_rosbags(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Reader

    path = tmp_path / "snap.bag"
    result = write_bag(_messages(10), {"/chatter": STRING, "/sim/pose": None}, path)
    assert result.messages == 10 and result.topics == ("/chatter",)
    assert result.skipped_topics == ("/sim/pose",)
    with Reader(path) as reader:
        (conn,) = reader.connections
        assert (conn.topic, conn.msgtype) == ("/chatter", "std_msgs/msg/String")
        got = [(ts, bytes(raw)) for _, ts, raw in reader.messages()]
    assert got[3] == (int((T0 + 0.3) * 1e9), ros1_string("hello 3"))


def test_bag_md5_is_computed_when_the_source_did_not_give_one(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Reader

    schema = TopicSchema("/chatter", "std_msgs/String", "ros1", "string data")
    write_bag(_messages(2), {"/chatter": schema}, tmp_path / "snap.bag")
    with Reader(tmp_path / "snap.bag") as reader:
        assert reader.connections[0].digest == STRING.md5sum


ROSBAG = Path("/usr/bin/rosbag")


@pytest.mark.ros1
@pytest.mark.skipif(not ROSBAG.exists() or not shutil.which("/usr/bin/python3"),
                    reason="Debian's rosbag is not installed (scripts/install-system-deps.sh)")
def test_bag_passes_debian_rosbag_info(tmp_path: Path) -> None:
    path = tmp_path / "snap.bag"
    write_bag(_messages(25), {"/chatter": STRING}, path)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["ROS_HOME"] = str(tmp_path)
    out = subprocess.run(["/usr/bin/python3", str(ROSBAG), "info", str(path)], env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    info = {line.split(":", 1)[0]: line.split(":", 1)[1].split()
            for line in out.stdout.splitlines() if ":" in line}
    assert info["messages"] == ["25"]
    assert info["types"] == ["std_msgs/String", "[992ce8a1687cec8c8bd883ec73ca41d1]"]
    assert info["topics"] == ["/chatter", "25", "msgs", ":", "std_msgs/String"]


def test_mcap_holds_ros1_and_json_topics(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    pose = TopicSchema("/sim/pose", "sim/Pose", "json",
                       '{"type": "object", "properties": {"x": {"type": "number"}}}')
    path = tmp_path / "snap.mcap"
    result = write_mcap(_messages(5), {"/chatter": STRING, "/sim/pose": pose}, path)
    assert result.messages == 10
    with path.open("rb") as fh:
        got = [(ch.topic, sc.encoding, ch.message_encoding, msg.data)
               for sc, ch, msg in make_reader(fh).iter_messages()]
    assert got[0] == ("/chatter", "ros1msg", "ros1", ros1_string("hello 0"))
    assert got[1] == ("/sim/pose", "jsonschema", "json", b'{"x": 0}')
