"""``blackbox evaluate --source ros1``: the seeded campaign on the real demo robot.

The real test starts Debian's ROS 1 thesis robot, injects the simulator's seeded faults into
its processes (memory growth, a wrong scale, a CPU hog, a drift, a stalled topic) and scores
the black box with the documented episode definition; it takes about 40 s.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from blackbox.app import DEFAULT_CONFIG
from blackbox.cli import main
from blackbox.evaluate import CampaignSettings
from blackbox.evaluate.metrics import score_run
from blackbox.evaluate.real_campaign import (
    ROBOT_HARNESSES,
    RealRun,
    ResourceUse,
    read_truth_log,
    run_real,
    schedule_for,
)
from blackbox.events import MeasurementGap
from blackbox.model import BlackBoxEvent
from blackbox.pipeline import RunStats
from blackbox.sources.sim import FAULT_KINDS, Topology

EXTENDED = DEFAULT_CONFIG.with_name("thesis-extended.yaml")
needs_ros1 = pytest.mark.skipif(shutil.which("roscore") is None or
                                not Path("/usr/bin/python3").exists(),
                                reason="needs Debian's ROS 1 (scripts/install-system-deps.sh)")


def test_a_campaign_on_a_named_master_is_refused_since_it_starts_its_own_robot(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--source", "ros1://127.0.0.1:11311", "--runs", "1"]) == 2
    err = capsys.readouterr().err
    assert "starts its own demo robot" in err and "give ros1 alone" in err


def test_a_source_with_neither_a_simulator_nor_a_harness_is_refused(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--source", "nosuchsource:x", "--runs", "1"]) == 2
    assert "--source" in capsys.readouterr().err


def test_ros1_campaigns_use_the_registered_harness_not_the_simulator() -> None:
    settings = CampaignSettings(source="ros1")
    settings.check()
    assert settings.harness() is ROBOT_HARNESSES.get("ros1")
    assert CampaignSettings(source="sim:thesis").harness() is None


def test_ground_truth_written_as_faults_happen_keeps_the_last_line_of_each_fault(
        tmp_path: Path) -> None:
    log = tmp_path / "truth.jsonl"
    begin = {"start": 10.0, "end": None, "kind": "kill", "component": "/usb_cam",
             "node": "/usb_cam", "params": {}}
    other = {"start": 12.0, "end": None, "kind": "rate", "component": "/signal",
             "node": "/Signal_generator", "params": {"factor": 0.5}}
    log.write_text("\n".join(json.dumps(r) for r in
                             (begin, other, {**begin, "end": 15.0})) + "\n")
    truth = read_truth_log(log)
    assert [(g.kind, g.end) for g in truth] == [("kill", 15.0), ("rate", None)]


def test_the_real_schedule_is_the_simulators_campaign_for_the_seed() -> None:
    a = schedule_for(Topology.thesis(), duration=60, tail=5, seed=4, kinds=("kill", "rate"),
                     mean_gap=5, warmup=5, separation=5)
    b = schedule_for(Topology.thesis(), duration=60, tail=5, seed=4, kinds=("kill", "rate"),
                     mean_gap=5, warmup=5, separation=5)
    assert a == b and a and {f["kind"] for f in a} <= {"kill", "rate"}
    assert all(5 <= f["start"] < 55 for f in a)


@needs_ros1
@pytest.mark.ros1
@pytest.mark.slow
def test_a_short_real_campaign_injects_on_the_processes_and_scores_them(tmp_path: Path) -> None:
    harness = ROBOT_HARNESSES["ros1"]
    # Every kind the real robot's injector knows (scripts/fault_injection.py has no noise).
    kinds = tuple(k for k in FAULT_KINDS if k != "noise")
    # Seed 2 over 30 s: memory growth, scale, CPU hog, drift, stall (see schedule_for).
    schedule = schedule_for(harness.topology(), duration=30, tail=5, seed=2, kinds=kinds,
                            mean_gap=3, warmup=3, separation=3)
    run = run_real(harness, config=EXTENDED, duration=30, tail=5, seed=2, kinds=kinds,
                   mean_gap=3, warmup=3, separation=3, diagnosis=True, work_dir=tmp_path)

    lines = [json.loads(x) for x in (tmp_path / "truth.jsonl").read_text().splitlines()]
    begun = [(r["kind"], r["component"]) for r in lines if r["end"] is None]
    assert begun == [(f["kind"], f["component"]) for f in schedule]
    for f, g in zip(schedule, run.truth, strict=True):
        assert (g.kind, g.component) == (f["kind"], f["component"])
        assert abs(g.start - (run.start + f["start"])) < 1.0, "injected at its offset"
        assert g.end is not None

    score = score_run(run.truth, run.observations, run.publishers, start=run.start,
                      end=run.end, grace=2.0, diagnoses=run.diagnoses)
    seen = {(o.fault.kind, o.fault.component): o for o in score.outcomes}
    # Not the CPU hog: on two cores shared with parallel tests it does not get the core it
    # spins for (its detection is specified on the simulator, tests/test_thesis_robot.py).
    for kind, component in (("scale", "/signal"), ("memory_growth", "/audio_capture"),
                            ("stall", "/audio")):
        outcome = seen[(kind, component)]
        assert outcome.detected, f"{kind} on {component} was not detected"
    assert run.resources.cpu_percent > 0 and run.resources.rss_max > 10e6
    assert run.events, "the run's events are kept for replaying the filter experiments"


def test_a_real_runs_measurement_gaps_and_source_reports_are_kept_for_its_json() -> None:
    """A false alarm or a miss is read against what the black box left unjudged and why:
    the closed gaps as offsets from the scored start, and the source's own reports."""
    starved = "the host starved /audio_capture of CPU"
    events = [MeasurementGap(100.5, 100.5, None, "switching", topic="/audio"),
              MeasurementGap(101.0, 100.5, 101.0, "switching", topic="/audio"),
              MeasurementGap(102.0, 101.5, 102.25, starved, topic="/audio"),
              MeasurementGap(103.0, 102.0, 103.0, "a thread of the black box waited 1.2 s"),
              BlackBoxEvent(102.0, "ros1_host_saturated", "host saturated", "robot"),
              BlackBoxEvent(102.5, "ros1_host_saturated", "host saturated", "robot")]
    run = RealRun(100.0, 200.0, [], [], [], list(events), RunStats(),
                  ResourceUse(1.0, 1.0, 1.0, 100.0))
    assert run.gaps() == [
        {"start": 0.5, "end": 1.0, "of": "/audio", "reason": "switching"},
        {"start": 1.5, "end": 2.25, "of": "/audio", "reason": starved},
        {"start": 2.0, "end": 3.0, "of": "everything",
         "reason": "a thread of the black box waited 1.2 s"}]
    assert run.reports() == {"ros1_host_saturated": 2}
