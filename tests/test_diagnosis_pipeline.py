"""Diagnosis in a running black box on the simulated thesis robot: one dead driver is one
diagnosis, not a cascade of alarms, with the model derived from the graph or from the
thesis's tug_diagnosis file."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest

from blackbox.app import RunOptions, build
from blackbox.model import Diagnosis
from blackbox.sinks import SinkBase
from conftest import SHARED

THESIS_MODEL = SHARED / "reference" / "thesis-setup" / "diagnosis_model.yaml"


class Diagnoses(SinkBase):
    def __init__(self) -> None:
        self.records: list[Diagnosis] = []

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        self.records.append(diagnosis)


def diagnose(tmp_path: Path, faults: str, duration: float, model: Path | None = None
             ) -> list[Diagnosis]:
    schedule = tmp_path / "faults.yaml"
    schedule.write_text(faults)
    config = tmp_path / "config.yaml"
    thesis = (Path(__file__).parent.parent / "src" / "blackbox" / "configs" / "thesis.yaml")
    text = thesis.read_text()
    if model is not None:
        text += f"diagnosis:\n  model: {model}\n"
    config.write_text(text)
    sink = Diagnoses()
    options = RunOptions(config=config, duration=duration, simulated_clock=True,
                         faults=str(schedule), live=False, extra_sinks=[sink])
    build(options).run()
    return sink.records


def during(records: Sequence[Diagnosis], start: float, end: float) -> list[Diagnosis]:
    return [d for d in records if start <= d.time < end]


@pytest.mark.parametrize("model", [None, THESIS_MODEL], ids=["derived", "tug-model"])
def test_dead_camera_driver_is_the_single_diagnosis(tmp_path: Path, model: Path | None) -> None:
    records = diagnose(tmp_path, "faults:\n  - {kind: kill, component: /usb_cam, start: 20, "
                       "end: 40}\n", 50.0, model)
    settled = during(records, 21.0, 40.0)[-1]
    assert settled.candidates[0] == frozenset({"/usb_cam"})
    assert all(len(c) == 1 for c in settled.candidates)
    assert {o.observer for o in settled.failed} >= {"activated", "timeout"}
    assert "/usb_cam" in settled.explanation
    assert records[-1].candidates == ()  # healthy again after the restart


def test_wrong_signal_value_blames_the_signal_generator(tmp_path: Path) -> None:
    records = diagnose(tmp_path, "faults:\n  - {kind: offset, component: /signal, start: 20, "
                       "end: 40, value: 3.0}\n", 45.0)
    settled = during(records, 20.0, 40.0)[-1]
    assert settled.candidates[0] == frozenset({"/Signal_generator"})
    assert [o.observer for o in settled.failed] == ["scores"]


def test_two_simultaneous_independent_faults_yield_the_pair(tmp_path: Path) -> None:
    records = diagnose(tmp_path, "faults:\n"
                       "  - {kind: kill, component: /usb_cam, start: 20, end: 40}\n"
                       "  - {kind: kill, component: /audio_capture, start: 20, end: 40}\n",
                       45.0)
    settled = during(records, 21.0, 40.0)[-1]
    assert settled.candidates[0] == frozenset({"/usb_cam", "/audio_capture"})
