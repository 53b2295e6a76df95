"""Rates from a publisher's ``getBusStats`` counters: parsing, counting, and asking for
them along with the liveness probe (real XML-RPC servers on loopback; no ROS needed; the
real robot over a shaped link is tests/test_netns_constrained_link.py)."""

from __future__ import annotations

import socket
import threading
from socketserver import ThreadingMixIn
from xmlrpc.server import SimpleXMLRPCRequestHandler, SimpleXMLRPCServer

from blackbox.sources.ros1.busstats import (
    STATS,
    STATS_AND_INFO,
    BusStatsRates,
    Connection,
    parse_bus_info,
    parse_bus_stats,
)
from blackbox.sources.ros1.master import RosApiError
from blackbox.sources.ros1.slave_probe import NodeReply, SlaveProbe

IMAGE = "/usb_cam/image_raw"


def test_rospy_bus_stats_and_info_are_read_per_connection() -> None:
    stats = [[[IMAGE, 5000, [[1, 4000, 4, True], [2, 1000, 1, False]]]], [], []]
    assert parse_bus_stats(stats) == {IMAGE: {1: (4, 4000, True), 2: (1, 1000, False)}}
    info = [[1, "/Signal_generator", "o", "TCPROS", IMAGE, True, ""],
            [7, "/usb_cam", "i", "TCPROS", "/other", True, ""]]
    assert parse_bus_info(info) == {1: "/Signal_generator"}


def test_malformed_replies_yield_nothing() -> None:
    assert parse_bus_stats("garbage") == {}
    assert parse_bus_stats([[["/t", 1, [["x", 1, 2, True]]], 5]]) == {"/t": {}}
    assert parse_bus_info([None, [1]]) == {}


def _conn(cid: int, dest: str, messages: int, connected: bool = True) -> Connection:
    return Connection(cid, dest, messages, messages * 1004, connected)


def test_the_busiest_live_robot_connection_gives_evenly_spaced_arrivals() -> None:
    rates = BusStatsRates()
    first = rates._count(10.0, IMAGE, "/usb_cam", [_conn(1, "/Signal_generator", 100)],
                         set())
    assert first.on_robot and first.arrivals == []  # one reading is no rate yet
    later = rates._count(11.0, IMAGE, "/usb_cam",
                         [_conn(1, "/Signal_generator", 115), _conn(2, "/slow", 105)], set())
    assert later.robot_sent == 15
    times = [a.time for a in later.arrivals]
    assert len(times) == 15 and times[0] > 11.0 and abs(times[-1] - 12.0) < 1e-9
    assert {a.size for a in later.arrivals} == {1000}  # 4-byte length prefix removed


def test_dead_or_closed_subscribers_and_the_black_box_itself_do_not_count() -> None:
    rates = BusStatsRates()
    conns = [_conn(1, "/Signal_generator", 100), _conn(2, "/blackbox", 50),
             _conn(3, "/gone", 10, connected=False)]
    rates._count(0.0, IMAGE, "/usb_cam", conns, set())
    r = rates._count(1.0, IMAGE, "/usb_cam",
                     [_conn(1, "/Signal_generator", 100), _conn(2, "/blackbox", 58),
                      _conn(3, "/gone", 10, connected=False)], {"/Signal_generator"})
    assert not r.on_robot and r.arrivals == [] and r.robot_sent is None
    assert r.own_sent == 8


def _stats(*conns: tuple[int, int]) -> list[object]:
    """A rospy ``getBusStats`` value for IMAGE: (connection id, messages) pairs."""
    return [[[IMAGE, 0, [[cid, m * 1004, m, True] for cid, m in conns]]], [], []]


def _info(*conns: tuple[int, str]) -> list[object]:
    return [[cid, dest, "o", "TCPROS", IMAGE, True, ""] for cid, dest in conns]


def test_bus_info_is_asked_only_when_a_count_names_a_connection_not_seen_in_that_process(
        ) -> None:
    rates = BusStatsRates(caller_id="/blackbox_me")
    pubs = {IMAGE: ("/usb_cam",)}
    assert rates.calls([IMAGE], pubs, set()) == {"/usb_cam": STATS_AND_INFO}
    rates.count(0.0, [IMAGE], pubs, {"/usb_cam": NodeReply(
        41, {"getBusStats": _stats((1, 100)), "getBusInfo": _info((1, "/viewer"))})}, set())
    assert rates.calls([IMAGE], pubs, set()) == {"/usb_cam": STATS}
    [r] = rates.count(1.0, [IMAGE], pubs, {"/usb_cam": NodeReply(
        41, {"getBusStats": _stats((1, 115))})}, set())
    assert r.robot_sent == 15 and len(r.arrivals) == 15
    # a second subscriber connects: unknown until its caller id is asked for, so it
    # counts for nobody (it might be the black box's own connection)
    [r] = rates.count(2.0, [IMAGE], pubs, {"/usb_cam": NodeReply(
        41, {"getBusStats": _stats((1, 130), (2, 900))})}, set())
    assert r.robot_sent == 15
    assert rates.calls([IMAGE], pubs, set()) == {"/usb_cam": STATS_AND_INFO}
    # the publisher restarted (new pid): connection ids start again, the old names go
    rates.count(3.0, [IMAGE], pubs, {"/usb_cam": NodeReply(
        57, {"getBusStats": _stats((1, 3))})}, set())
    assert rates.calls([IMAGE], pubs, set()) == {"/usb_cam": STATS_AND_INFO}
    assert rates.calls([IMAGE], pubs, {"/usb_cam"}) == {}


def test_a_publisher_without_counts_this_round_starts_afresh() -> None:
    rates = BusStatsRates()
    pubs = {IMAGE: ("/usb_cam",)}
    both = {"getBusStats": _stats((1, 100)), "getBusInfo": _info((1, "/viewer"))}
    rates.count(0.0, [IMAGE], pubs, {"/usb_cam": NodeReply(41, both)}, set())
    error = RosApiError("getBusStats on http://x: no answer (timed out)")
    assert rates.count(1.0, [IMAGE], pubs,
                       {"/usb_cam": NodeReply(41, {"getBusStats": error})}, set()) == []
    [r] = rates.count(2.0, [IMAGE], pubs, {"/usb_cam": NodeReply(
        41, {"getBusStats": _stats((1, 400))})}, set())
    assert r.arrivals == [] and r.on_robot  # no burst of 300 from the gap


class _Slave(threading.Thread):
    """A real XML-RPC slave API on loopback answering getPid / getBusStats / getBusInfo,
    with or without ``system.multicall`` (rospy and roscpp have it; others may not)."""

    def __init__(self, multicall: bool, messages: int = 7) -> None:
        super().__init__(daemon=True)
        self.server = SimpleXMLRPCServer(("127.0.0.1", 0), logRequests=False)
        self.server.register_function(lambda caller: [1, "", 4242], "getPid")
        self.server.register_function(lambda caller: [1, "", _stats((1, messages))],
                                      "getBusStats")
        self.server.register_function(lambda caller: [1, "", _info((1, "/viewer"))],
                                      "getBusInfo")
        if multicall:
            self.server.register_multicall_functions()
        self.uri = f"http://127.0.0.1:{self.server.server_address[1]}/"
        self.requests = 0
        handle = self.server._dispatch

        def counted(method: str, params: tuple[object, ...]) -> object:
            self.requests += 1
            return handle(method, params)
        self.server._dispatch = counted  # type: ignore[method-assign]

    def run(self) -> None:
        self.server.serve_forever(poll_interval=0.05)

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def test_extra_calls_ride_on_the_liveness_probe_in_one_request() -> None:
    # rospy cannot encode a counter past 2**31 (2 GB of camera images on one connection):
    # the whole batch faults, yet the node is alive
    batching, plain, overflow = (_Slave(multicall=True), _Slave(multicall=False),
                                 _Slave(multicall=True, messages=2**31))
    for slave in (batching, plain, overflow):
        slave.start()
    try:
        replies = SlaveProbe().probe({"/a": batching.uri, "/b": plain.uri, "/c": "http://127.0.0.1:9/",
                               "/d": overflow.uri},
                              timeout=2.0, extra={"/a": STATS_AND_INFO, "/b": STATS,
                                                  "/d": STATS})
    finally:
        for slave in (batching, plain, overflow):
            slave.stop()
    a, b, c, d = replies["/a"], replies["/b"], replies["/c"], replies["/d"]
    assert a.pid == 4242 and a.multicall
    assert a.extra == {"getBusStats": _stats((1, 7)), "getBusInfo": _info((1, "/viewer"))}
    # one HTTP request whose three calls the server dispatched itself
    assert batching.requests == 1 + 3
    # no system.multicall: the pid alone, asked again within the same deadline
    assert b.pid == 4242 and not b.multicall
    assert isinstance(b.extra["getBusStats"], RosApiError)
    assert isinstance(c.pid, RosApiError) and "refused" in str(c.pid)
    assert d.pid == 4242 and not d.multicall
    assert "int exceeds XML-RPC limits" in str(d.extra["getBusStats"])
    rates = BusStatsRates()
    assert rates.count(0.0, [IMAGE], {IMAGE: ("/d",)}, {"/d": d}, set()) == []
    assert "exceeds" in rates.unavailable["/d"]


class _KeepAliveSlave(threading.Thread):
    """A slave API served like rospy's: HTTP/1.1, one thread per kept connection."""

    def __init__(self) -> None:
        super().__init__(daemon=True)

        class Handler(SimpleXMLRPCRequestHandler):
            protocol_version = "HTTP/1.1"

        class Server(ThreadingMixIn, SimpleXMLRPCServer):
            daemon_threads = True

        self.server = Server(("127.0.0.1", 0), requestHandler=Handler, logRequests=False)
        self.server.register_function(lambda caller: [1, "", 4242], "getPid")
        self.uri = f"http://127.0.0.1:{self.server.server_address[1]}/"

    def run(self) -> None:
        self.server.serve_forever(poll_interval=0.05)

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def test_the_probe_keeps_its_connection_to_a_node_and_reopens_one_the_node_closed() -> None:
    slave = _KeepAliveSlave()
    slave.start()
    probe = SlaveProbe()
    try:
        for _ in range(5):
            assert probe.probe({"/n": slave.uri}, timeout=2.0)["/n"].pid == 4242
        assert probe.connects == 1  # one connection, five answers
        kept = probe._kept["/n"][1]
        kept.shutdown(socket.SHUT_RDWR)  # as a node closing an idle connection looks
        assert probe.probe({"/n": slave.uri}, timeout=2.0)["/n"].pid == 4242
        assert probe.connects == 2
    finally:
        probe.close()
        slave.stop()


def test_a_node_that_stops_answering_is_dead_and_its_connection_is_not_reused() -> None:
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen()  # accepts (the kernel does) but never answers: a SIGSTOPped node
    uri = f"http://127.0.0.1:{listener.getsockname()[1]}/"
    probe = SlaveProbe()
    try:
        for connects in (1, 2):
            reply = probe.probe({"/stopped": uri}, timeout=0.2)["/stopped"]
            assert isinstance(reply.pid, RosApiError) and "timed out" in str(reply.pid)
            assert probe.connects == connects and "/stopped" not in probe._kept
    finally:
        probe.close()
        listener.close()
