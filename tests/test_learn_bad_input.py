"""Learning from a robot that does not behave: no traffic, no graph at all, a node that dies
while learning, too little data, messages that do not decode. Every case gives a file that
loads and says in comments what could not be learned; none raises."""

from __future__ import annotations

from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.events import GraphSnapshot, MessageArrival, NodeInfo, TopicInfo
from blackbox.learn import Learned, learn_from, render_config
from blackbox.learn.model import TIMEOUT_FLOOR
from blackbox.observe.build import load_config_text
from blackbox.sources.memory import MemorySource
from blackbox.sources.sim import Fault, SimulatedSource, Topology, open_sim

SLOW_ROBOT = """\
name: slow
nodes:
  - name: /driver
  - name: /beacon
topics:
  - name: /value
    type: std_msgs/Float64
    publisher: /driver
    rate: 10
    value: {field: data, mean: 1.0, noise: 0.1}
  - name: /beacon
    type: std_msgs/Float64
    publisher: /beacon
    rate: 0.5
    value: {field: data, mean: 3.0, noise: 0.1}
"""


def flat(text: str) -> str:
    return " ".join(line.strip().lstrip("#").strip() for line in text.splitlines())


def rendered(learned: Learned) -> tuple[str, list[dict]]:
    text = render_config(learned, "r", "r.model.yaml", "now")
    config = load_config_text(text, "r.yaml")
    return flat(text), [e.to_python() for e in config.observers]


def graph(t: float) -> GraphSnapshot:
    return GraphSnapshot(t, {"/driver": NodeInfo("/driver", True, 10)},
                         {"/value": TopicInfo("/value", "std_msgs/Float64", ("/driver",), ())})


def test_a_robot_without_traffic_gives_liveness_only_and_says_why() -> None:
    events = [graph(float(t)) for t in range(31)]
    learned = learn_from(lambda: MemorySource(events), 30.0)
    text, entries = rendered(learned)
    assert "no message arrived on any topic during 30 s" in text
    assert "topic /value: no message in 30 s: neither rate nor values learned" in text
    assert [e["type"] for e in entries] == ["activated"]


def test_a_source_without_any_graph_gives_an_empty_but_loadable_file() -> None:
    learned = learn_from(lambda: MemorySource([]), 5.0, discovery_timeout=1.0)
    text, entries = rendered(learned)
    assert entries == []
    assert "the source showed no graph snapshot within 1 s of discovery" in text
    assert "nothing could be learned" in text


def test_a_node_that_dies_while_learning_is_learned_from_the_time_it_ran() -> None:
    faults = [Fault("kill", "/audio_capture", 20, 35), Fault("kill", "/usb_cam", 50, None)]
    learned = learn_from(lambda: open_sim("sim:thesis", faults=faults, seed=4,
                                          realtime=False), 90.0)
    text, entries = rendered(learned)
    assert "node /audio_capture: not running from 20.0 s to 35.0 s of the run" in text
    assert "node /usb_cam: not running from 50.0 s to the end of the run" in text
    timeout = next(e for e in entries if e["type"] == "timeout" and e["topic"] == "/audio")
    assert timeout["timeout"] <= TIMEOUT_FLOOR  # the 15 s outage is not a healthy gap
    assert "gap(s) while a publisher was not running left out of the periods" in text
    assert any(e["type"] == "activated" and e["node"] == "/usb_cam" for e in entries)


def test_too_little_data_for_a_topic_is_said_not_guessed(tmp_path: Path) -> None:
    robot = Topology.parse(SLOW_ROBOT, "slow.yaml")
    learned = learn_from(lambda: SimulatedSource(robot, seed=1), 20.0)
    text, entries = rendered(learned)
    assert "topic /beacon: rate: only 9 periods measured (need 20)" in text
    assert "data: only 10 samples (need 20): not observed" in text
    assert not any(e.get("topic") == "/beacon" for e in entries)
    assert any(e["type"] == "hz" and e["topic"] == "/value" for e in entries)


def test_messages_that_do_not_decode_are_counted_not_fatal() -> None:
    def broken() -> object:
        raise ValueError("truncated buffer")

    events = [graph(0.0)] + [MessageArrival(0.1 * i, "/value", "/driver", 8, decode=broken)
                             for i in range(1, 100)]
    learned = learn_from(lambda: MemorySource(events), 10.0)
    text, entries = rendered(learned)
    assert "values not learned: does not decode: truncated buffer" in text
    assert {e["type"] for e in entries} == {"activated", "hz", "timeout"}


def test_cli_on_a_silent_robot_explains_and_writes(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    robot = tmp_path / "silent.yaml"
    robot.write_text(SLOW_ROBOT.replace("rate: 10", "rate: 0.01").replace("rate: 0.5",
                                                                           "rate: 0.01"))
    out = tmp_path / "out.yaml"
    assert main(["learn", "--source", f"sim:{robot}", "--simulated-clock", "--duration", "20",
                 "-o", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "could not learn: topic /value: rate: only 0 periods measured" in err
    assert out.is_file()
    assert main(["check-config", str(out)]) == 0


def test_cli_without_a_master_says_so_without_waiting_out_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import socket
    import time

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "none.yaml"
    started = time.monotonic()
    assert main(["learn", "--source", f"ros1://127.0.0.1:{port}", "--duration", "600",
                 "--discovery", "2", "-o", str(out), "--quiet"]) == 1
    assert time.monotonic() - started < 60  # the 600 s run is skipped
    err = capsys.readouterr().err
    assert "could not learn: the source showed no node and no topic within 2 s of discovery" \
        in err
    assert "refused" in err  # why: the master does not answer
    assert "nothing could be learned" in out.read_text()
