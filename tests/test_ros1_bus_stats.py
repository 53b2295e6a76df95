"""Rates from a publisher's ``getBusStats`` counters: parsing and counting (no ROS needed;
the real robot over a shaped link is tests/test_netns_constrained_link.py)."""

from __future__ import annotations

from blackbox.sources.ros1.busstats import (
    BusStatsRates,
    Connection,
    parse_bus_info,
    parse_bus_stats,
)

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
    try:
        first = rates._count(10.0, IMAGE, "/usb_cam", [_conn(1, "/Signal_generator", 100)],
                             set())
        assert first.on_robot and first.arrivals == []  # one reading is no rate yet
        later = rates._count(11.0, IMAGE, "/usb_cam",
                             [_conn(1, "/Signal_generator", 115), _conn(2, "/slow", 105)], set())
        assert later.robot_sent == 15
        times = [a.time for a in later.arrivals]
        assert len(times) == 15 and times[0] > 11.0 and abs(times[-1] - 12.0) < 1e-9
        assert {a.size for a in later.arrivals} == {1000}  # 4-byte length prefix removed
    finally:
        rates.close()


def test_dead_or_closed_subscribers_and_the_black_box_itself_do_not_count() -> None:
    rates = BusStatsRates()
    try:
        conns = [_conn(1, "/Signal_generator", 100), _conn(2, "/blackbox", 50),
                 _conn(3, "/gone", 10, connected=False)]
        rates._count(0.0, IMAGE, "/usb_cam", conns, set())
        r = rates._count(1.0, IMAGE, "/usb_cam",
                         [_conn(1, "/Signal_generator", 100), _conn(2, "/blackbox", 58),
                          _conn(3, "/gone", 10, connected=False)], {"/Signal_generator"})
        assert not r.on_robot and r.arrivals == [] and r.robot_sent is None
        assert r.own_sent == 8
    finally:
        rates.close()
