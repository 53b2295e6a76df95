"""The ROS 2 source against real rclpy nodes (Fast DDS, loopback, one domain per test)."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from blackbox.config.node import ConfigError
from blackbox.events import Interest
from blackbox.sources import open_source
from blackbox.sources.ros2 import Ros2Settings, Ros2Source, domain_id_from_spec
from blackbox.sources.ros2.idl import IdlTypes, ros_type_name
from blackbox.sources.ros2.qos import EndpointQos, incompatibilities
from isolation import fresh_domain
from ros2_support import Watched, needs_rclpy, ros2_robot

THESIS_TOPICS = frozenset({"/usb_cam/image_raw", "/audio", "/signal"})


# ---- without ROS ---------------------------------------------------------------------------

def test_spec_names_the_domain_or_takes_it_from_ros_domain_id() -> None:
    assert domain_id_from_spec("ros2", {}) == 0
    assert domain_id_from_spec("ros2", {"ROS_DOMAIN_ID": "42"}) == 42
    assert domain_id_from_spec("ros2:7", {"ROS_DOMAIN_ID": "42"}) == 7
    for bad in ("ros2:x", "ros2:233", "ros2:-1"):
        with pytest.raises(ConfigError, match="domain id"):
            domain_id_from_spec(bad, {})
    assert isinstance(open_source("ros2:3"), Ros2Source)


def test_reader_types_come_from_the_type_store_under_ros2_dds_names() -> None:
    types = IdlTypes()
    image = types.struct("sensor_msgs/msg/Image")
    assert image.__idl_typename__ == "sensor_msgs::msg::dds_::Image_"
    assert ros_type_name("std_msgs::msg::dds_::Float64_") == "std_msgs/msg/Float64"
    assert ros_type_name("DDS::ParticipantBuiltinTopicData") is None
    sample = types.struct("std_msgs/msg/Float64")(data=2.5)
    assert types.store.deserialize_cdr(sample.serialize(), "std_msgs/msg/Float64").data == 2.5


def test_qos_incompatibilities_follow_the_request_offered_rules() -> None:
    be = EndpointQos("best_effort")
    rel = EndpointQos("reliable")
    durable = EndpointQos("reliable", "transient_local")
    assert incompatibilities(rel, be) == []
    assert incompatibilities(durable, rel) == []
    assert incompatibilities(be, rel)[0].startswith("reliability")
    assert incompatibilities(rel, durable)[0].startswith("durability")


# ---- against rclpy -------------------------------------------------------------------------

@pytest.fixture
def domain() -> int:
    return fresh_domain()


@pytest.fixture
def robot(domain: int, tmp_path: Path) -> Iterator[object]:
    r = ros2_robot.ThesisRobot2(domain, log_dir=tmp_path / "logs")
    try:
        yield r
    finally:
        r.stop()


def _watch(domain: int, **kw: object) -> Watched:
    return Watched(domain, Interest(THESIS_TOPICS, frozenset({"/signal"}),
                                    resources=frozenset({"/usb_cam"})), **kw)  # type: ignore[arg-type]


@needs_rclpy
@pytest.mark.ros2
def test_graph_arrivals_values_and_resources_of_the_thesis_robot_without_joining_it(
        robot, domain: int) -> None:

    robot.start()
    watched = _watch(domain)
    observer = ros2_robot.ParameterClient(domain)
    try:
        assert watched.until(lambda: all(len(watched.arrivals(t)) >= 10
                                         for t in THESIS_TOPICS), 20)
        graph = watched.graphs()[-1]
        assert graph.nodes["/usb_cam"].alive
        assert graph.nodes["/usb_cam"].pid == robot.nodes["/usb_cam"].pid
        image = graph.topics["/usb_cam/image_raw"]
        assert image.type == "sensor_msgs/msg/Image"
        assert image.publishers == ("/usb_cam",)
        assert image.subscribers == ("/Signal_generator",)
        # per publisher, typed values decoded lazily, sizes of the CDR payload
        assert {a.publisher for a in watched.arrivals("/signal")} == {"/Signal_generator"}
        assert 14.0 <= watched.arrivals("/signal")[-1].value.data <= 16.0
        camera = watched.arrivals("/usb_cam/image_raw")[-1]
        assert camera.size > 640 * 480 * 3
        assert camera.value is None  # not asked to decode: never decoded
        # QoS of each observed endpoint is reported
        shown = [e.message for e in watched.reports("ros2_endpoint")]
        assert any(m.startswith("publisher /usb_cam on /usb_cam/image_raw") and "reliable" in m
                   for m in shown)
        assert watched.until(lambda: any(
            getattr(e, "cpu_percent", None) is not None for e in watched.events), 5)
        # the robot's own graph API does not see the black box as a node
        assert observer.wait_for_node("/Signal_generator", 10)
        names = {f"{ns.rstrip('/')}/{n}" for n, ns in
                 observer.node.get_node_names_and_namespaces()}
        assert names == {"/usb_cam", "/audio_capture", "/Signal_generator",
                         "/blackbox_test_injector"}
    finally:
        observer.close()
        watched.close()


@needs_rclpy
@pytest.mark.ros2
def test_a_killed_node_is_reported_dead_within_one_second(robot, domain: int) -> None:
    robot.start(["/audio_capture"])
    watched = _watch(domain)
    try:
        assert watched.until(lambda: any(
            g.nodes.get("/audio_capture") and g.nodes["/audio_capture"].alive
            for g in watched.graphs()), 20)
        killed = time.time()
        robot.kill("/audio_capture", signal.SIGKILL)
        assert watched.until(lambda: any(
            g.time >= killed and not g.nodes["/audio_capture"].alive
            for g in watched.graphs()), 3)
        first_dead = next(g for g in watched.graphs()
                          if g.time >= killed and not g.nodes["/audio_capture"].alive)
        assert first_dead.time - killed <= 1.0
        assert any("/audio_capture is dead" in e.message
                   for e in watched.reports("ros2_node_dead"))
    finally:
        watched.close()


@needs_rclpy
@pytest.mark.ros2
def test_an_incompatible_qos_pair_is_reported_and_the_reader_still_reads(
        robot, domain: int) -> None:
    robot.start_node("/Signal_generator", "--reliability", "best_effort")
    robot.start_node("/listener", "--topic", "/signal", "--reliability", "reliable")
    watched = _watch(domain)
    try:
        assert watched.until(lambda: bool(watched.reports("ros2_qos_incompatible")), 20)
        report = watched.reports("ros2_qos_incompatible")[0]
        assert report.component == "/signal"
        assert "publisher /Signal_generator and subscriber /listener" in report.message
        assert "reliability" in report.message
        # the black box picks a best-effort reader, so it still hears the publisher
        assert watched.until(lambda: len(watched.arrivals("/signal")) >= 5, 10)
    finally:
        watched.close()


@needs_rclpy
@pytest.mark.ros2
def test_a_type_the_store_does_not_know_is_reported_and_its_rate_still_observed(
        robot, domain: int) -> None:
    store = get_typestore(Stores.ROS2_KILTED)
    del store.fielddefs["std_msgs/msg/Float64"]
    robot.start(["/Signal_generator"])
    watched = _watch(domain, settings=Ros2Settings(typestore=store))
    try:
        assert watched.until(lambda: len(watched.arrivals("/signal")) >= 10, 20)
        report = watched.reports("ros2_unknown_type")[0]
        assert report.component == "/signal" and "std_msgs/msg/Float64" in report.message
        arrival = watched.arrivals("/signal")[-1]
        assert arrival.publisher == "/Signal_generator"
        assert arrival.value is None
        assert arrival.size == 8
    finally:
        watched.close()


@pytest.mark.ros2
def test_an_empty_domain_says_so_and_never_hangs(domain: int) -> None:
    watched = _watch(domain, settings=Ros2Settings(no_participant_grace=0.5))
    try:
        started = time.monotonic()
        assert watched.until(lambda: bool(watched.reports("ros2_no_participants")), 3)
        assert time.monotonic() - started < 3
        assert f"domain {domain}" in watched.reports("ros2_no_participants")[0].message
    finally:
        watched.close()


@needs_rclpy
@pytest.mark.ros2
def test_a_topic_is_unmeasured_from_the_start_until_its_first_message(robot, domain: int) -> None:
    """Discovery and node names take seconds; the messages held back meanwhile are not the
    robot's silence, so a time-out must not count them. A topic nobody publishes is judged
    again after ``first_message_limit``."""
    robot.start(["/audio_capture"])
    watched = Watched(domain, Interest(frozenset({"/audio", "/nobody"})),
                      settings=Ros2Settings(first_message_limit=8.0))
    try:
        assert watched.until(lambda: len(watched.gaps("/nobody")) == 2
                             and bool(watched.arrivals("/audio")), 20), \
            "the start gap of /nobody closed and /audio arrived within 20 s"
        opened, closed = watched.gaps("/audio")[:2]
        assert opened.end is None and closed.start == opened.start
        first = watched.arrivals("/audio")[0]
        assert closed.end == first.time, "measured from the first message on"
        assert [e for e in watched.events if getattr(e, "topic", None) == "/audio"][:2] == [
            opened, closed], "nothing of /audio is handed out inside its gap"
        nobody = watched.gaps("/nobody")[1]
        assert nobody.end is not None and 8.0 <= nobody.end - nobody.start < 9.0
        assert "no message within 8 s" in nobody.reason
    finally:
        watched.close()
