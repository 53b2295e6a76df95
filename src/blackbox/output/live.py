"""The live status view of ``blackbox run``.

On a terminal it redraws a table of every observed characteristic (at most ``fps`` times
per wall-clock second, so a fast simulated run stays cheap); elsewhere (a pipe, a log file)
it prints one line per state change instead, which is what a log reader wants.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Sequence
from typing import IO

from blackbox.model import BlackBoxEvent, Code, Diagnosis, Observation, Resource
from blackbox.safetext import terminal_text
from blackbox.sinks import SinkBase

_COLOURS = {"OK": "\x1b[32m", "FAULT": "\x1b[31m", "N/A": "\x1b[33m"}
_RESET = "\x1b[0m"


def status_word(code: Code) -> str:
    if code == Code.NOT_AVAILABLE:
        return "N/A"
    return "FAULT" if code < 0 else "OK"


def format_time(t: float) -> str:
    """Wall-clock times as local time of day; simulated clocks as seconds since start."""
    if t > 1e8:
        return time.strftime("%H:%M:%S", time.localtime(t)) + f".{int(t * 1000) % 1000:03d}"
    return f"{t:10.3f}"


def format_values(obs: Observation) -> str:
    parts = []
    for name, value in list(obs.values.items())[:3]:
        parts.append(f"{name}={value:.4g}" if isinstance(value, float) else f"{name}={value}")
    return " ".join(parts)


class LiveStatusView(SinkBase):
    """Renders the latest observation per characteristic, the diagnosis and recent events."""

    def __init__(self, stream: IO[str] | None = None, *, fps: float = 4.0, title: str = "",
                 interactive: bool | None = None) -> None:
        self.stream = stream or sys.stdout
        self.interactive = self.stream.isatty() if interactive is None else interactive
        self.title = title
        self._min_gap = 1.0 / fps
        self._last_draw = 0.0
        self._latest: dict[tuple[str, Resource], Observation] = {}
        self._diagnosis: Diagnosis | None = None
        self._events: deque[BlackBoxEvent] = deque(maxlen=5)
        self._now = 0.0

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        self._now = now
        for obs in observations:
            key = obs.key()
            before = self._latest.get(key)
            self._latest[key] = obs
            if not self.interactive and (before is None or status_word(before.code)
                                         != status_word(obs.code)):
                self._line(f"{format_time(now)} {status_word(obs.code):5} {obs.observer:9} "
                           f"{obs.resource.label()}: {obs.message}")
        if self.interactive:
            self._maybe_draw()

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        self._diagnosis = diagnosis
        if not self.interactive:
            self._line(f"{format_time(diagnosis.time)} DIAG  {self.diagnosis_line(diagnosis)}")
        else:
            self._maybe_draw(force=True)

    def on_event(self, event: BlackBoxEvent) -> None:
        self._events.append(event)
        if not self.interactive:
            self._line(f"{format_time(event.time)} EVENT {event.kind}: {event.message}")

    def close(self) -> None:
        if self.interactive:
            self._draw()

    @staticmethod
    def diagnosis_line(diagnosis: Diagnosis) -> str:
        if not diagnosis.candidates:
            return "all components healthy"
        shown = ["{" + ", ".join(sorted(c)) + "}" for c in diagnosis.candidates[:3]]
        more = f" (+{len(diagnosis.candidates) - 3} more)" if len(diagnosis.candidates) > 3 else ""
        return "faulty: " + " or ".join(shown) + more

    # ---- drawing -------------------------------------------------------------------------------

    def _line(self, text: str) -> None:
        self.stream.write(terminal_text(text) + "\n")  # names come from the robot's graph
        self.stream.flush()

    def _maybe_draw(self, force: bool = False) -> None:
        wall = time.monotonic()
        if force or wall - self._last_draw >= self._min_gap:
            self._last_draw = wall
            self._draw()

    def render(self) -> str:
        """The table as text (without terminal control codes, also none from the robot)."""
        lines = [f"{self.title}  {format_time(self._now).strip()}  "
                 f"{sum(1 for o in self._latest.values() if o.code < 0)} faulty of "
                 f"{len(self._latest)} observed"]
        lines.append(f"{'STATUS':6} {'OBSERVER':10} {'RESOURCE':38} {'VALUES':32} MESSAGE")
        for obs in sorted(self._latest.values(), key=lambda o: (o.resource.label(), o.observer)):
            word = status_word(obs.code)
            lines.append(f"{word:6} {obs.observer:10} {obs.resource.label()[:38]:38} "
                         f"{format_values(obs)[:32]:32} {obs.message[:60]}")
        if self._diagnosis is not None:
            lines.append("")
            lines.append("DIAGNOSIS: " + self.diagnosis_line(self._diagnosis))
            if self._diagnosis.candidates and self._diagnosis.explanation:
                lines.append("  " + self._diagnosis.explanation[:300])
        if self._events:
            lines.append("")
            lines.extend(f"event {format_time(e.time).strip()} {e.kind}: {e.message[:90]}"
                         for e in self._events)
        return "\n".join(terminal_text(line) for line in lines)

    def _draw(self) -> None:
        text = self.render()
        for word, colour in _COLOURS.items():
            text = text.replace(f"\n{word:6}", f"\n{colour}{word:6}{_RESET}")
        self.stream.write("\x1b[H\x1b[J" + text + "\n")
        self.stream.flush()
