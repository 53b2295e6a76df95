"""``blackbox evaluate --report DIR`` and the thesis's filter experiments on the simulator."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from blackbox.app import DEFAULT_CONFIG
from blackbox.cli import main
from blackbox.evaluate import CampaignSettings, run_campaign
from blackbox.evaluate.filter_experiments import (
    FILTER_TYPES,
    config_with_filter,
    simulated_filter_experiments,
)
from blackbox.evaluate.report import make_report
from blackbox.observe.build import build_observers, load_config_text

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("kind", FILTER_TYPES)
def test_every_filtered_observer_gets_the_filter_under_test(kind: str) -> None:
    text = config_with_filter(DEFAULT_CONFIG, kind, 20)
    data = yaml.safe_load(text)
    filters = [o["filter"] for o in data["observers"] if "filter" in o]
    assert len(filters) == 4  # three hz and one scores observer in the thesis set
    assert all(f["type"] == kind and f["window_size"] == 20 for f in filters)
    assert len(build_observers(load_config_text(text, kind))) == 10


def test_longer_mean_windows_detect_rate_and_value_faults_later(tmp_path: Path) -> None:
    points = simulated_filter_experiments(DEFAULT_CONFIG, tmp_path,
                                          kinds=("rate", "offset", "scale"), runs=1,
                                          duration=120, fault_free=30, filters=("mean",),
                                          windows=(2, 100))
    short, long = points
    assert short.detected == short.faults > 0
    assert short.delay_p50 is not None and long.delay_p50 is not None
    assert long.delay_p50 > short.delay_p50


def test_the_report_has_its_figures_tables_and_the_thesis_side_by_side(tmp_path: Path) -> None:
    settings = CampaignSettings(runs=1, duration=60)
    result = run_campaign(settings)
    seen: list[str] = []
    path = make_report(settings, result, tmp_path / "report", "text report here\n",
                       fault_free=20, windows=(2, 50), filter_runs=1, progress=seen.append)
    text = path.read_text()
    for png in ("recall_delay_by_kind.png", "delay_distribution.png",
                "fig_6_10_false_positives.png", "fig_6_11_detection_delay.png"):
        assert (tmp_path / "report" / png).read_bytes().startswith(PNG)
        assert f"]({png})" in text
    assert "text report here" in text and "Fig. 6.10" in text and "Fig. 6.11" in text
    filters = json.loads((tmp_path / "report" / "filters.json").read_text())
    assert len(filters["simulator"]) == 4 * 2 and filters["real"] is None
    assert len(seen) == 8 and seen[-1].startswith("filters (simulator) 8/8")


def test_the_command_writes_the_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                       ) -> None:
    assert main(["evaluate", "--runs", "1", "--duration", "30", "--quiet", "--report",
                 str(tmp_path), "--fault-free", "10"]) == 0
    assert (tmp_path / "report.md").exists()
    assert f"wrote {tmp_path / 'report.md'}" in capsys.readouterr().out
