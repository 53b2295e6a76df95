"""JSON lines files of observations, diagnoses and black-box events.

One JSON object per line, schema in ``docs/observations.md``. Each line carries
``"record"`` (``observation``, ``diagnosis`` or ``event``) and ``"schema": 1`` so readers
can tell versions apart. Lines are flushed after every evaluation, so a killed black box
leaves at most one partial last line.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

from blackbox.model import BlackBoxEvent, Diagnosis, Observation
from blackbox.sinks import SinkBase

SCHEMA_VERSION = 1


class JsonLinesSink(SinkBase):
    """Writes the records it is given to one JSON lines file."""

    def __init__(self, path: str | Path, *, observations: bool = True, diagnoses: bool = True,
                 events: bool = True) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[str] = self.path.open("a", encoding="utf-8")
        self._observations = observations
        self._diagnoses = diagnoses
        self._events = events

    def _write(self, kind: str, body: dict[str, Any]) -> None:
        body = {"record": kind, "schema": SCHEMA_VERSION, **body}
        self._file.write(json.dumps(body, separators=(",", ":"), default=float) + "\n")

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        if not self._observations:
            return
        for obs in observations:
            self._write("observation", obs.to_dict())
        self._file.flush()

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        if self._diagnoses:
            self._write("diagnosis", diagnosis.to_dict())
            self._file.flush()

    def on_event(self, event: BlackBoxEvent) -> None:
        if self._events:
            self._write("event", event.to_dict())
            self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def read_records(path: str | Path) -> list[dict[str, Any]]:
    """Read a JSON lines file back, skipping a partial last line left by a crash."""
    records = []
    with Path(path).open(encoding="utf-8") as f:
        for line in f:
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return records
