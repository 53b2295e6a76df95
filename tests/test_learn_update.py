"""`blackbox learn --update`: learned blocks are refined (bounds only ever widen), everything
outside them survives byte for byte, and a hand-written observer wins over a learned one."""

from __future__ import annotations

import functools
from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.config.node import ConfigError
from blackbox.learn import Learned, learn_from, render_config, update_config
from blackbox.learn.update import merge_values, split_blocks
from blackbox.observe.build import load_config, load_config_text
from blackbox.sources.sim import Fault, open_sim

HAND_HEADER = "# my robot, tuned by hand on 2026-11-20\n"
HAND_OBSERVER = """\
  # hand-written: /audio may run a little slow when the microphone warms up
  - type: hz
    topic: /audio
    filter: {type: median, window_size: 30}
    states:
      - {number: 1, name: ok, period: {value: {type: less_than, less_than: 0.05}}}
"""


SHARES_LEARNED_RUNS = pytest.mark.xdist_group("test_learn_update_runs")
"""On one worker: the three learning runs these tests share are made once per process."""


@functools.cache
def learned(seed: int, slow_signal: bool = False) -> Learned:
    faults = [Fault("rate", "/signal", 0, None, {"factor": 0.9})] if slow_signal else []
    return learn_from(lambda: open_sim("sim:thesis", faults=faults, seed=seed,
                                       realtime=False), 60.0)


def hand_edited() -> str:
    text = render_config(learned(1), "robot-7", "robot.model.yaml", "first")
    text = HAND_HEADER + text.replace("observers:\n", "observers:\n" + HAND_OBSERVER, 1)
    return text + "recorder:\n  path: bb.db   # hand-written section after the observers\n"


def entry(text: str, kind: str, topic: str) -> dict:
    for e in load_config_text(text, "x.yaml").observers:
        py = e.to_python()
        if py["type"] == kind and (py.get("topic") or py.get("node")) == topic:
            return py
    raise AssertionError(f"no {kind} {topic}")


def outside_blocks(text: str) -> str:
    return "".join(s.text for s in split_blocks(text, "x.yaml")
                   if s.block is None)


@SHARES_LEARNED_RUNS
def test_update_keeps_hand_edits_and_widens_learned_bounds() -> None:
    before = hand_edited()
    after = update_config(before, "robot.yaml", learned(2, slow_signal=True),
                          "robot.model.yaml", "second")
    assert outside_blocks(after) == outside_blocks(before)
    assert HAND_HEADER in after and HAND_OBSERVER in after and "path: bb.db" in after
    old = entry(before, "hz", "/signal")["states"][0]["period"]["value"]
    new_only = entry(render_config(learned(2, True), "r", "m", "x"), "hz",
                     "/signal")["states"][0]["period"]["value"]
    merged = entry(after, "hz", "/signal")["states"][0]["period"]["value"]
    assert merged["lower_bound"] == min(old["lower_bound"], new_only["lower_bound"])
    assert merged["upper_bound"] == max(old["upper_bound"], new_only["upper_bound"])
    assert new_only["upper_bound"] > old["upper_bound"]   # the slower run widened it
    assert "robot-7" in after and "source sim:thesis, 60 s, second" in after


@SHARES_LEARNED_RUNS
def test_a_hand_written_observer_wins_over_the_learned_one() -> None:
    after = update_config(hand_edited(), "robot.yaml", learned(2), "robot.model.yaml", "2nd")
    hz_audio = [e.to_python() for e in load_config_text(after, "x").observers
                if e["type"].str() == "hz" and e["topic"].str() == "/audio"]
    assert len(hz_audio) == 1 and hz_audio[0]["filter"]["type"] == "median"
    flat = " ".join(line.strip().lstrip("#").strip() for line in after.splitlines())
    assert "a hand-written hz observer of /audio outside this block is kept" in flat
    assert entry(after, "timeout", "/audio")["timeout"] > 0  # the rest of the block stays


@SHARES_LEARNED_RUNS
def test_blocks_the_new_run_did_not_see_are_kept_with_a_note() -> None:
    partial = learned(2)
    partial = Learned(partial.source, partial.duration, partial.nodes,
                      [b for b in partial.topics if b.id != "topic /audio"],
                      partial.graph, partial.notes)
    after = update_config(hand_edited(), "robot.yaml", partial, "robot.model.yaml", "3rd")
    block = next(s for s in split_blocks(after, "x") if s.block == "topic /audio")
    assert "not seen in the update run (3rd); kept as it was" in block.text
    assert entry(after, "timeout", "/audio")


def test_update_of_a_hand_written_file_adds_blocks_after_its_observers(tmp_path: Path) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text("version: 1\nrobot: {id: mine}\nobservers:\n"
                    "  - {type: activated, node: /usb_cam}   # mine\n")
    assert main(["learn", "--source", "sim:thesis", "--simulated-clock", "--duration", "30",
                 "--update", str(path), "--quiet"]) == 0
    text = path.read_text()
    assert text.startswith("# >>> learned summary >>>")
    assert "  - {type: activated, node: /usb_cam}   # mine\n" in text
    assert "diagnosis:\n  # >>> learned diagnosis model >>>" in text
    config = load_config(path)
    activated = [e for e in config.observers if e["type"].str() == "activated"
                 and e["node"].str() == "/usb_cam"]
    assert len(activated) == 1  # the hand-written one; the learned one is left out
    assert (tmp_path / "mine.model.yaml").is_file()


def test_broken_markers_and_broken_files_are_clear_errors(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    text = hand_edited()
    cut = text.replace("  # <<< learned topic /signal <<<\n", "", 1)
    with pytest.raises(ConfigError, match=r"never closed|starts inside") as err:
        update_config(cut, "robot.yaml", learned(2), "m.yaml", "x")
    assert err.value.line > 0
    path = tmp_path / "broken.yaml"
    path.write_text("observers:\n  - {type: hz, topic: /a, filter: {type: mean, window_sise: 3}}\n")
    assert main(["learn", "--source", "sim:thesis", "--simulated-clock", "--duration", "5",
                 "--update", str(path), "--quiet"]) == 2
    assert "window_sise" in capsys.readouterr().err
    assert path.read_text().startswith("observers:")  # left untouched


def test_merge_rule() -> None:
    old = {"type": "hz", "timeout": 0.5, "filter": {"type": "mean", "window_size": 20},
           "states": [{"number": 1, "period": {"value": {"type": "in_between",
                                                          "lower_bound": 1.0,
                                                          "upper_bound": 2.0}}}]}
    new = {"type": "hz", "timeout": 0.4, "filter": {"type": "mean", "window_size": 10},
           "states": [{"number": 1, "period": {"value": {"type": "in_between",
                                                          "lower_bound": 1.2,
                                                          "upper_bound": 2.5}}}]}
    old["states"][0]["period"]["deviation"] = [{"type": "greater_than", "greater_than": 0.1}]
    new["states"][0]["period"]["deviation"] = [{"type": "greater_than", "greater_than": 0.2}]
    merged = merge_values(old, new)
    assert merged["states"][0]["period"].pop("deviation") == [{"type": "greater_than",
                                                              "greater_than": 0.1}]
    assert merged["timeout"] == 0.5 and merged["filter"]["window_size"] == 20
    assert merged["states"][0]["period"]["value"] == {"type": "in_between",
                                                      "lower_bound": 1.0, "upper_bound": 2.5}
