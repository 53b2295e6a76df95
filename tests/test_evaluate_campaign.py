"""Fault-injection campaigns end to end on the simulated thesis robot, and ``blackbox
evaluate`` through the real command line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from blackbox.app import DEFAULT_CONFIG
from blackbox.cli import main
from blackbox.evaluate import KIND_SETS, CampaignSettings, Confusion, parse_kinds, run_campaign
from blackbox.sources.sim import FAULT_KINDS, THESIS_FAULT_KINDS, Topology, random_campaign

pytestmark = pytest.mark.xdist_group("test_evaluate_campaign")  # its module fixture: one worker

EXTENDED = DEFAULT_CONFIG.with_name("thesis-extended.yaml")


@pytest.fixture(scope="module")
def short_campaign():
    return run_campaign(CampaignSettings(runs=2, duration=60.0, seed=0))


def test_short_campaign_scores_every_injected_fault_once(short_campaign) -> None:
    for run in short_campaign.runs:
        planned = random_campaign(Topology.thesis(), 55.0, run.seed, THESIS_FAULT_KINDS,
                                  min_separation=5.0)
        assert planned, "a 60 s run has faults to score"
        assert [(o.fault.kind, o.fault.component, o.fault.start) for o in run.score.outcomes] == (
            [(f.kind, f.component, f.start) for f in planned])
        c = run.score.confusion
        assert c.tp + c.fn == len(planned)
        assert c.tp == sum(o.detected for o in run.score.outcomes)
        assert c.fp == len(run.score.false_positives)
        assert run.score.false_positives == tuple(
            e for e in run.score.false_positives if e in run.score.episodes)
        # TN counts OK evaluations, so it cannot exceed them.
        assert 0 < c.tn <= run.stats.observations - run.stats.faulty_observations
        assert run.score.end == pytest.approx(60.0)
    assert [r.seed for r in short_campaign.runs] == [0, 1]


def test_short_campaign_totals_add_up_and_measures_are_ratios(short_campaign) -> None:
    total = Confusion()
    for run in short_campaign.runs:
        total = total + run.score.confusion
    c = short_campaign.confusion
    assert c == total
    assert len(short_campaign.outcomes) == c.tp + c.fn
    assert sum(k.faults for k in short_campaign.kinds) == c.tp + c.fn
    assert sum(k.detected for k in short_campaign.kinds) == c.tp
    for value in (c.accuracy, c.accuracy_without_tn, c.precision, c.recall, c.f1):
        assert value is not None and 0.0 <= value <= 1.0
    assert {k.kind for k in short_campaign.kinds} <= set(THESIS_FAULT_KINDS)
    assert all(d >= 0.0 for d in short_campaign.delays())
    diagnosis = short_campaign.diagnosis
    assert diagnosis is not None and diagnosis.faults == c.tp + c.fn


def test_same_settings_give_the_same_result() -> None:
    settings = CampaignSettings(runs=1, duration=40.0, seed=7)
    assert run_campaign(settings).to_dict() == run_campaign(settings).to_dict()


def test_extended_configuration_sees_all_fault_kinds() -> None:
    """Sanity bound: with all nine fault kinds on the extended configuration, recall >= 0.9.
    Seen while writing this: recall 1.0 for all 30 campaigns starting at seeds 0, 2, ..., 58
    (2 x 120 s each, seeds 0-59), and >= 0.913 even with back-to-back faults (separation 0)."""
    result = run_campaign(CampaignSettings(config=EXTENDED, runs=2, duration=120.0, seed=0,
                                           kinds=KIND_SETS["all"]))
    assert len(result.outcomes) >= 10
    assert result.confusion.recall is not None and result.confusion.recall >= 0.9


def test_plain_thesis_configuration_cannot_see_resource_faults() -> None:
    """The thesis's ten observers watch no CPU or memory: such faults are injected and
    counted as missed, not dropped from the score."""
    result = run_campaign(CampaignSettings(runs=1, duration=120.0, seed=0,
                                           kinds=("cpu_hog", "memory_growth"), diagnosis=False))
    c = result.confusion
    assert len(result.outcomes) > 0
    assert (c.tp, c.fn) == (0, len(result.outcomes))
    assert c.recall == 0.0 and result.diagnosis is None


def test_kinds_option() -> None:
    assert parse_kinds("thesis") == THESIS_FAULT_KINDS
    assert parse_kinds("all") == tuple(FAULT_KINDS)
    assert parse_kinds("kill, stall") == ("kill", "stall")
    with pytest.raises(ValueError, match="--kinds: unknown fault kind 'explode'"):
        parse_kinds("kill,explode")
    assert parse_kinds("none") == ()


def test_a_healthy_campaign_injects_nothing_and_counts_every_alarm_as_false(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--kinds none``: the healthy hours of issue 23. No fault is injected (an empty kind
    list must not fall back to every kind), so TP and FN are 0 and any alarm is an FP."""
    out = tmp_path / "healthy.json"
    assert main(["evaluate", "--quiet", "--kinds", "none", "--runs", "1", "--duration", "60",
                 "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["settings"]["kinds"] == []
    assert data["totals"]["faults"] == data["totals"]["tp"] == data["totals"]["fn"] == 0
    run = data["runs"][0]
    assert run["faults"] == [] and run["observations"] > 0
    assert data["totals"]["fp"] == len(run["false_positives"])
    # the simulator's healthy thesis robot: what a healthy hour must show on a real one
    assert data["totals"]["fp"] == 0


@pytest.mark.parametrize(("settings", "message"), [
    (CampaignSettings(runs=0), "--runs"),
    (CampaignSettings(duration=8.0), "--duration: a run must last more than 10 s"),
    (CampaignSettings(grace=-1.0), "--grace"),
    (CampaignSettings(mean_gap=0.0), "--mean-gap"),
    (CampaignSettings(source="ros1://127.0.0.1:11311"),
     "--source: a campaign starts its own demo robot"),
    (CampaignSettings(source="nosuch:x"), "--source: unknown source"),
])
def test_bad_settings_are_refused_by_name(settings: CampaignSettings, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        run_campaign(settings)


def test_cli_prints_runs_totals_and_the_thesis_side_by_side(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "eval" / "result.json"
    assert main(["evaluate", "--runs", "2", "--duration", "40", "--seed", "3",
                 "--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert "run 1/2 (seed 3)" in captured.err and "run 2/2 (seed 4)" in captured.err
    text = captured.out
    for needle in ("thesis 1-10", "thesis 11-20", "71.6 %", "0.83", "0.93", "delay p50",
                   "accuracy, TN = 0 (as thesis)", "detection per fault kind"):
        assert needle in text
    data = json.loads(out.read_text())
    totals = data["totals"]
    assert totals["tp"] + totals["fn"] == totals["faults"] == sum(
        len(r["faults"]) for r in data["runs"])
    assert [r["seed"] for r in data["runs"]] == [3, 4]
    assert data["settings"]["kinds"] == list(THESIS_FAULT_KINDS)
    assert data["thesis"][1]["tp"] == 276
    first = data["runs"][0]["faults"][0]
    assert {"kind", "component", "start", "end", "detected", "delay"} <= set(first)


@pytest.mark.parametrize(("argv", "message"), [
    (["--kinds", "explode"], "error: --kinds: unknown fault kind"),
    (["--runs", "0"], "error: --runs"),
    (["--source", "ros1://127.0.0.1:1"], "error: --source"),
    (["--source", "sim:nowhere"], "error: --source"),
])
def test_cli_bad_options_exit_2_with_one_line(
        argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(message) and "Traceback" not in err


def test_cli_missing_configuration_is_a_configuration_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--quiet", "--runs", "1", "--duration", "20",
                 "--config", str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml" in capsys.readouterr().err
