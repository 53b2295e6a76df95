"""The simulated robot's topology file: what it accepts and how it reports mistakes."""

from __future__ import annotations

import pytest

from blackbox.config.node import ConfigError
from blackbox.sources.sim import (
    BytesModel,
    ImageModel,
    NodeSpec,
    ScalarModel,
    TopicSpec,
    Topology,
)

MINIMAL = """\
name: tiny
nodes:
  - name: /driver
    cpu: 5
  - name: /consumer
topics:
  - name: /value
    type: std_msgs/Float64
    publisher: /driver
    rate: 10
    subscribers: [/consumer]
    value: {field: data, mean: 1.0, noise: 0.1}
"""


def error_of(text: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        Topology.parse(text, "robot.yaml")
    return info.value


def test_thesis_robot_matches_the_experiment_setup():
    robot = Topology.thesis()
    assert list(robot.nodes) == ["/usb_cam", "/audio_capture", "/Signal_generator"]
    cam = robot.topics["/usb_cam/image_raw"]
    assert (cam.type, cam.publisher, cam.rate) == ("sensor_msgs/Image", "/usb_cam", 15.0)
    assert cam.value == ImageModel(640, 480, "rgb8")
    assert cam.value.payload == 921_600
    audio = robot.topics["/audio"]
    assert audio.type == "audio_common_msgs/AudioData"
    assert audio.rate == pytest.approx(1 / 0.03, rel=1e-3)
    assert isinstance(audio.value, BytesModel)
    signal = robot.topics["/signal"]
    assert (signal.type, signal.publisher, signal.rate) == ("std_msgs/Float64",
                                                            "/Signal_generator", 15.0)
    assert signal.value == ScalarModel("data", 15.0, 0.5, "uniform")
    assert cam.subscribers == audio.subscribers == ("/Signal_generator",)
    # the thesis signal generator keeps publishing when an input dies
    assert robot.nodes["/Signal_generator"].requires == ()
    assert robot.interface == "eth0"
    assert robot.published_by("/usb_cam") == ("/usb_cam/image_raw",)


def test_minimal_file_fills_in_defaults():
    robot = Topology.parse(MINIMAL)
    assert robot.name == "tiny"
    assert robot.nodes["/driver"].cpu == 5.0
    assert robot.nodes["/consumer"].memory == 20e6
    assert robot.nodes["/driver"].pid != robot.nodes["/consumer"].pid
    assert robot.topics["/value"].jitter == 0.0


def test_unknown_key_names_file_line_and_suggests_spelling():
    err = error_of(MINIMAL.replace("    rate: 10", "    rat: 10"))
    assert (err.file, err.line, err.path) == ("robot.yaml", 10, "topics[0].rat")
    assert "did you mean 'rate'" in err.message
    assert str(err).startswith("robot.yaml:10:")


def test_missing_rate_is_reported_at_the_topic():
    err = error_of(MINIMAL.replace("    rate: 10\n", ""))
    assert (err.line, err.path) == (7, "topics[0]")
    assert "'rate'" in err.message


def test_unknown_publisher_is_reported_at_its_line():
    err = error_of(MINIMAL.replace("publisher: /driver", "publisher: /drivr"))
    assert (err.line, err.path) == (9, "topics[0].publisher")
    assert "unknown node /drivr" in err.message


def test_unknown_subscriber_is_reported_at_its_item():
    err = error_of(MINIMAL.replace("[/consumer]", "[/consumer, /ghost]"))
    assert err.path == "topics[0].subscribers[1]"


def test_unknown_message_type_asks_for_a_definition():
    err = error_of(MINIMAL.replace("std_msgs/Float64", "my_msgs/Reading"))
    assert (err.line, err.path) == (8, "topics[0].type")
    assert "types:" in err.message


def test_custom_types_are_declared_with_their_definition():
    text = MINIMAL.replace("std_msgs/Float64", "my_msgs/Reading").replace(
        "name: tiny\n", "name: tiny\ntypes:\n  my_msgs/Reading: \"float32 data\\nuint32 id\"\n")
    robot = Topology.parse(text)
    assert robot.topics["/value"].type == "my_msgs/Reading"


def test_broken_definition_is_a_config_error():
    err = error_of(MINIMAL.replace("name: tiny\n", "name: tiny\ntypes:\n  my/T: \"flot32 x[\"\n"))
    assert "my/T" in err.message


def test_value_field_must_be_numeric():
    err = error_of(MINIMAL.replace("std_msgs/Float64", "std_msgs/String"))
    assert err.path == "topics[0].value.field"
    assert "no numeric field 'data'" in err.message


def test_image_value_needs_an_image_type():
    err = error_of(MINIMAL.replace("{field: data, mean: 1.0, noise: 0.1}",
                                   "{image: {width: 4, height: 2}}"))
    assert err.path == "topics[0].value.image"


def test_unknown_noise_distribution():
    err = error_of(MINIMAL.replace("noise: 0.1}", "noise: 0.1, distribution: gaus}"))
    assert err.path == "topics[0].value.distribution"
    assert "did you mean 'gauss'" in err.message


def test_duplicate_nodes_are_rejected():
    err = error_of(MINIMAL.replace("name: /consumer", "name: /driver"))
    assert (err.line, err.path) == (5, "nodes[1].name")


def test_node_names_must_be_graph_names():
    err = error_of(MINIMAL.replace("name: /consumer", "name: consumer"))
    assert err.path == "nodes[1].name"


def test_jitter_must_stay_well_under_a_period():
    err = error_of(MINIMAL.replace("rate: 10\n", "rate: 10\n    jitter: 0.05\n"))
    assert err.path == "topics[0].jitter"


def test_requires_must_name_an_input_of_the_node():
    text = MINIMAL.replace("  - name: /driver\n",
                           "  - name: /driver\n    requires: {topics: [/value]}\n")
    err = error_of(text)
    assert err.path == "nodes[0].requires.topics[0]"
    assert "not one of its subscribers" in err.message


def test_requires_with_timeout():
    text = MINIMAL.replace("  - name: /consumer\n",
                           "  - name: /consumer\n    requires: {topics: /value, timeout: 0.5}\n")
    node = Topology.parse(text).nodes["/consumer"]
    assert (node.requires, node.requires_timeout) == (("/value",), 0.5)


def test_python_construction_is_validated_too():
    nodes = {"/a": NodeSpec("/a", 1)}
    with pytest.raises(ValueError, match="unknown publisher node /b"):
        Topology("x", nodes, {"/t": TopicSpec("/t", "std_msgs/Float64", "/b", 1.0)})
    with pytest.raises(ValueError, match="unknown message type"):
        Topology("x", nodes, {"/t": TopicSpec("/t", "nope/Nope", "/a", 1.0)})


def test_missing_file():
    with pytest.raises(ConfigError, match="file not found"):
        Topology.load("/nonexistent/robot.yaml")
