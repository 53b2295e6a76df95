"""docs/recorder.md shows how the recorder is wired into a pipeline: that block runs as
it stands (it once showed a ``pipeline.add_sink`` that never existed)."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

from blackbox.record import Store
from conftest import ROOT


def integration_block() -> str:
    text = (ROOT / "docs" / "recorder.md").read_text()
    section = text[text.index("## Integration (pipeline side)"):]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "docs/recorder.md has a python block under Integration"
    return match.group(1)


def test_the_integration_example_records_a_run(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    shutil.copy(ROOT / "src/blackbox/configs/thesis.yaml", tmp_path / "robot.yaml")
    monkeypatch.chdir(tmp_path)
    exec(compile(integration_block(), "docs/recorder.md", "exec"), {})
    assert os.path.exists("blackbox.db")
    with Store.open(tmp_path / "blackbox.db", readonly=True) as store:
        events = [e.payload.get("event") for e in store.query(kinds=["blackbox_event"])
                  if e.entity == "blackbox/recorder"]
        assert events[0] == "start" and events[-1] == "stop"
        assert store.count("config") == 1
        assert store.count("observation") > 0
        recorder_health = [e for e in store.query(kinds=["observation"])
                           if e.entity == "/blackbox/recorder"]
        assert recorder_health, "the recorder's own health is observed and logged"
