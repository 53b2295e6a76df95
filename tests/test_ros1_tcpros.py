"""TCPROS framing, headers, decoding and source specs, over real sockets but without ROS."""

from __future__ import annotations

import socket
import struct
import threading
import time
from typing import Any

import pytest

from blackbox.config.node import ConfigError
from blackbox.events import MessageArrival, NodeInfo
from blackbox.sources.ros1.decoder import MessageDecoder, ros2_style_type
from blackbox.sources.ros1.resources import ResourceSampler
from blackbox.sources.ros1.source import master_uri_from_spec
from blackbox.sources.ros1.stream_reader import StreamKey, TcprosReader
from blackbox.sources.ros1.wire import HeaderError, decode_header, encode_header
from conftest import wait_for

FLOAT64_DEF = "float64 data\n"
POINT_DEF = """Header header
geometry_msgs/Point[] points
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
"""


def test_header_round_trip_matches_the_wire_format() -> None:
    raw = encode_header({"topic": "/a", "md5sum": "*"})
    # total 4 + (4 + 8) + (4 + 8) bytes: each field is its length then key=value
    assert raw == (struct.pack("<I", 24) + struct.pack("<I", 8) + b"topic=/a"
                   + struct.pack("<I", 8) + b"md5sum=*")
    assert decode_header(raw[4:]) == {"topic": "/a", "md5sum": "*"}


def test_header_value_may_contain_equals_and_newlines() -> None:
    raw = encode_header({"message_definition": "a=b\nint32 x\n"})
    assert decode_header(raw[4:]) == {"message_definition": "a=b\nint32 x\n"}


@pytest.mark.parametrize(("body", "reason"), [
    (struct.pack("<I", 100) + b"topic=/a", "overruns"),
    (struct.pack("<I", 5) + b"topic", "without '='"),
    (b"\x01\x00", "truncated"),
    (struct.pack("<I", 3) + b"a=\xff", "not UTF-8"),
])
def test_malformed_headers_are_rejected_with_a_reason(body: bytes, reason: str) -> None:
    with pytest.raises(HeaderError, match=reason):
        decode_header(body)


def test_type_names_become_rosbags_names() -> None:
    assert ros2_style_type("sensor_msgs/Image") == "sensor_msgs/msg/Image"
    assert ros2_style_type("sensor_msgs/msg/Image") == "sensor_msgs/msg/Image"


def test_decoder_reaches_nested_fields_and_array_elements() -> None:
    decoder = MessageDecoder()
    name = decoder.register("my_msgs/Cloud", POINT_DEF)
    frame = b"map"
    data = (struct.pack("<III", 7, 1, 2) + struct.pack("<I", len(frame)) + frame
            + struct.pack("<I", 2) + struct.pack("<3d", 1, 2, 3) + struct.pack("<3d", 4, 5, 6))
    msg = decoder.decode(data, name)
    assert msg.header.seq == 7
    assert msg.header.frame_id == "map"
    assert msg.points[1].y == 5.0
    # registering the same definition again is a no-op, not a conflict
    assert decoder.register("my_msgs/Cloud", POINT_DEF) == name


class _Collected:
    def __init__(self) -> None:
        self.messages: list[MessageArrival] = []
        self.closed: list[tuple[StreamKey, str, int]] = []
        self.first: list[StreamKey] = []
        self.done = threading.Event()

    def on_message(self, m: MessageArrival) -> None:
        self.messages.append(m)

    def on_closed(self, key: StreamKey, reason: str, count: int) -> None:
        self.closed.append((key, reason, count))
        self.done.set()


def _reader(path: str, decoder: MessageDecoder | None = None
            ) -> tuple[TcprosReader, _Collected]:
    got = _Collected()
    reader = TcprosReader(got.on_message, got.on_closed, got.first.append,
                          decoder or MessageDecoder())
    assert reader.native == (path == "native")
    reader.start()
    return reader, got


def _frames(payloads: list[bytes]) -> bytes:
    return b"".join(struct.pack("<I", len(p)) + p for p in payloads)


def _tcp_pair() -> tuple[socket.socket, socket.socket]:
    with socket.create_server(("127.0.0.1", 0)) as server:
        theirs = socket.create_connection(server.getsockname())
        ours, _ = server.accept()
    return ours, theirs


@pytest.mark.parametrize("pair", [socket.socketpair, _tcp_pair], ids=["unix", "tcp"])
def test_reader_splits_a_byte_stream_into_messages_however_it_arrives(
        pair: Any, receive_path: str) -> None:
    """Length prefixes and bodies split across writes, an empty message, one large body
    (over TCP the kernel drops its bytes uncopied and wakes the reader when it is whole)."""
    reader, got = _reader(receive_path)
    ours, theirs = pair()
    payloads = [b"abc", b"", b"x" * 700_000, b"\x01\x02\x03\x04\x05"]
    stream = _frames(payloads)
    key = StreamKey("/t", "/pub")
    try:
        reader.add(key, ours, max_bytes=1_000_000, decode_as=None)
        for cut in (1, 2, 3, 5, 9, 300_000, 700_010):  # odd cuts split prefixes and bodies
            theirs.sendall(stream[:cut])
            stream = stream[cut:]
            time.sleep(0.01)
        theirs.sendall(stream)
        theirs.close()
        assert got.done.wait(5)
    finally:
        reader.close()
    assert [m.size for m in got.messages] == [3, 0, 700_000, 5]
    assert {m.publisher for m in got.messages} == {"/pub"}
    assert got.messages[0].value is None  # timing-only topics are never decoded
    assert got.first == [key]
    assert got.closed == [(key, "publisher closed the connection", 4)]


def test_decoded_topics_keep_their_bytes_and_decode_lazily(receive_path: str) -> None:
    decoder = MessageDecoder()
    name = decoder.register("std_msgs/Float64", FLOAT64_DEF)
    reader, got = _reader(receive_path, decoder)
    ours, theirs = socket.socketpair()
    try:
        reader.add(StreamKey("/v", "/pub"), ours, max_bytes=64, decode_as=name)
        theirs.sendall(_frames([struct.pack("<d", 15.25), b"\x01"]))  # second is garbage
        theirs.close()
        assert got.done.wait(5)
    finally:
        reader.close()
    good, bad = got.messages
    assert good.value.data == 15.25
    assert good.raw() == struct.pack("<d", 15.25)
    assert bad.value is None  # undecodable bytes give no value instead of an exception


def test_an_absurd_length_prefix_closes_only_that_connection_with_a_reason(
        receive_path: str) -> None:
    reader, got = _reader(receive_path)
    ours, theirs = socket.socketpair()
    try:
        reader.add(StreamKey("/t", "/evil"), ours, max_bytes=1000, decode_as=None)
        theirs.sendall(_frames([b"ok"]) + struct.pack("<I", 0xFFFFFFF0) + b"junk")
        assert got.done.wait(5)
    finally:
        reader.close()
        theirs.close()
    assert [m.size for m in got.messages] == [2]
    (key, reason, count), = got.closed
    assert key == StreamKey("/t", "/evil")
    assert reason == ("message length prefix of 4294967280 bytes exceeds the cap of 1000 "
                      "bytes for /t (garbage or oversized message)")
    assert count == 1


def test_source_specs() -> None:
    assert master_uri_from_spec("ros1://robot:11311") == "http://robot:11311/"
    assert master_uri_from_spec("ros1", {"ROS_MASTER_URI": "http://10.0.0.2:11311"}) == \
        "http://10.0.0.2:11311"
    for bad in ("ros1://robot", "ros1://robot:x", "ros1://:11311", "ros1://h:1/path"):
        with pytest.raises(ConfigError, match="expected ros1://HOST:PORT"):
            master_uri_from_spec(bad)
    with pytest.raises(ConfigError, match="ROS_MASTER_URI"):
        master_uri_from_spec("ros1", {})
    with pytest.raises(ConfigError, match="not an http"):
        master_uri_from_spec("ros1", {"ROS_MASTER_URI": "robot:11311"})


def test_remote_and_dead_nodes_have_no_resource_numbers_but_a_reason() -> None:
    sampler = ResourceSampler()
    nodes = {"/far": NodeInfo("/far", True, 1234, "192.0.2.7"),
             "/dead": NodeInfo("/dead", False, None, "127.0.0.1")}
    dead, far, gone = sampler.sample(5.0, frozenset({"/far", "/dead", "/gone"}), nodes)
    assert (dead.node, dead.cpu_percent, dead.memory_bytes) == ("/dead", None, None)
    assert "not running" in dead.reason
    assert far.cpu_percent is None and far.memory_bytes is None
    assert "runs on host 192.0.2.7" in far.reason
    assert "not in the ROS graph" in gone.reason


def test_caller_ids_are_unique_per_source_and_ros_names() -> None:
    from blackbox.sources.ros1.callerid import unique_caller_id, valid_caller_id
    from blackbox.sources.ros1.source import Ros1Settings, parse_source_spec

    a, b = unique_caller_id(host="my-pi.local", pid=42), unique_caller_id(host="my-pi.local",
                                                                          pid=42)
    assert a.startswith("/blackbox_my_pi_local_42_") and a != b
    assert valid_caller_id(a) and valid_caller_id(b)
    with pytest.raises(ValueError):
        unique_caller_id("blackbox")
    base, settings = parse_source_spec("ros1://h:1?caller_id=/bb_front&counters=0",
                                       Ros1Settings())
    assert (base, settings.caller_id, settings.rates_from_counters) == (
        "ros1://h:1", "/bb_front", False)
    for bad in ("ros1://h:1?caller_id=bb", "ros1://h:1?callerid=/bb", "ros1://h:1?caller_id=",
                "ros1://h:1?counters=2"):
        with pytest.raises(ConfigError):
            parse_source_spec(bad, Ros1Settings())


def test_arrival_time_is_when_the_bytes_reached_the_socket_not_when_they_were_read() -> None:
    from blackbox.sources.ros1.stream_reader import _ANCILLARY, SO_TIMESTAMPNS, kernel_time

    if SO_TIMESTAMPNS is None:
        pytest.skip("no SO_TIMESTAMPNS on this platform")
    server = socket.create_server(("127.0.0.1", 0))
    client = socket.create_connection(server.getsockname())
    peer, _ = server.accept()
    try:
        peer.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        # the first timestamping socket on the machine switches stamping on through
        # deferred kernel work; until then arrivals are stamped when read
        time.sleep(0.1)
        sent = time.time()
        client.sendall(b"\x00" * 8)
        time.sleep(0.3)  # a reader that is late
        _, ancillary, _, _ = peer.recvmsg_into([bytearray(64)], _ANCILLARY)
        assert kernel_time(ancillary) == pytest.approx(sent, abs=0.05)
        assert kernel_time([]) == pytest.approx(time.time(), abs=0.05)  # no stamp: now
    finally:
        for s in (client, peer, server):
            s.close()


def test_the_arrivals_of_one_read_are_handed_on_together(receive_path: str) -> None:
    batches: list[list[MessageArrival]] = []
    got = _Collected()
    reader = TcprosReader(got.on_message, got.on_closed, got.first.append, MessageDecoder(),
                          on_batch=batches.append)
    reader.start()
    a, b = socket.socketpair()
    try:
        reader.add(StreamKey("/t", "/pub"), b, 1 << 20, None)
        a.sendall(_frames([b"x" * 10] * 50))
        assert wait_for(lambda: sum(map(len, batches)) == 50, timeout=5.0)
        assert len(batches) < 50 and got.messages == []
        assert all(m.topic == "/t" and m.size == 10 for batch in batches for m in batch)
    finally:
        reader.close()
        a.close()


def test_compact_reader_hands_on_one_batch_per_receive_and_counts_every_message(
        receive_path: str) -> None:
    from blackbox.events import ArrivalBatch

    handed: list[list[Any]] = []
    got = _Collected()
    reader = TcprosReader(got.on_message, got.on_closed, got.first.append, MessageDecoder(),
                          on_batch=handed.append, compact=True, coalesce=0.02)
    reader.start()
    a, b = socket.socketpair()
    try:
        reader.add(StreamKey("/t", "/pub"), b, 1 << 20, None)
        for i in range(40):  # one message per write, as rospy sends them
            a.sendall(_frames([bytes(i % 7)]))
            time.sleep(0.002)
        assert wait_for(lambda: sum(x.count for h in handed for x in h) == 40, timeout=5.0)
        items = [x for h in handed for x in h]
        assert all(type(x) is ArrivalBatch and x.topic == "/t" for x in items)
        assert sum(x.bytes for x in items) == sum(i % 7 for i in range(40))
        # at most one wake-up per 20 ms: far fewer receives than messages
        assert len(items) < 20 and got.messages == []
        assert got.first == [StreamKey("/t", "/pub")]
    finally:
        reader.close()
        a.close()


def test_source_options_for_reader_processes_and_coalescing() -> None:
    from blackbox.sources.ros1.source import Ros1Settings, parse_source_spec

    base, s = parse_source_spec("ros1://127.0.0.1:11311?readers=2&coalesce=0.001",
                                Ros1Settings())
    assert base == "ros1://127.0.0.1:11311" and (s.readers, s.coalesce) == (2, 0.001)
    for bad, why in (("readers=-1", "bad readers"), ("readers=x", "bad readers"),
                     ("readers=1000", "bad readers"), ("coalesce=1", "bad coalesce"),
                     ("coalesce=abc", "bad coalesce")):
        with pytest.raises(ConfigError, match=why):
            parse_source_spec(f"ros1?{bad}", Ros1Settings())
