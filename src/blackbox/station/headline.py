"""One line an operator reads at a glance: what is not working, since when, how sure, what
to do; the evidence behind it as a short structured list, shown one click away.

Pure functions over the station's records (:class:`~blackbox.station.store.Event`,
:class:`~blackbox.station.store.Diagnosis`): the follower stores a failure's UCMS fields
(cause, operator and maintenance action, the candidate explanations in the complementary
information) in the event's details, and this module turns them into words. Nothing here
reads the database, so the robot page, the events page and the live updates all say the
same thing.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

CODE_WORDS = {"NOT_AVAILABLE": "is not running", "TIMEOUT": "has gone silent",
              "NO_STATE_FITS": "behaves unlike any expected state"}
"""Plain words for the observation codes a failure names (``blackbox.model.Code``)."""
DEFAULT_WORDS = "is not working"
_FAILED = re.compile(r"(\d+) of (\d+) observations failed: (.*?)(?:\.\s|\.$|$)", re.S)
_BEST_OF = re.compile(r"best of (\d+) candidate explanations")


@dataclass(frozen=True, slots=True)
class Evidence:
    """One labelled group of the evidence list, e.g. ``Failed observations: [a, b]``."""

    label: str
    items: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Headline:
    """What a page shows first for a diagnosis or an event."""

    text: str
    severity: str
    """``bad`` (a failure), ``warn`` (an exceedance, stale data), ``good`` or ``info``."""
    since: float | None = None
    certainty: str = ""
    """``unique`` or ``one of N explanations``; empty when not a diagnosis."""
    operator_action: str = ""
    maintenance_action: str = ""
    evidence: tuple[Evidence, ...] = field(default_factory=tuple)

    def to_dict(self, now: float) -> dict[str, Any]:
        """For the live-update stream (the JavaScript renders the same fields)."""
        return {"text": self.text, "when": since_words(self.since, now),
                "severity": self.severity, "certainty": self.certainty,
                "operator_action": self.operator_action,
                "maintenance_action": self.maintenance_action,
                "evidence": [{"label": e.label, "items": list(e.items)}
                             for e in self.evidence]}


def duration_words(seconds: float) -> str:
    """``12 s``, ``4 min 05 s``, ``2 h 10 min``, ``3 d 4 h``: as long as it has lasted."""
    s = max(0, int(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    if s < 86400:
        return f"{s // 3600} h {s % 3600 // 60:02d} min"
    return f"{s // 86400} d {s % 86400 // 3600} h"


def since_words(since: float | None, now: float) -> str:
    """``since 17:02:31, 12 s`` (UTC; the date too when not today)."""
    if since is None:
        return ""
    at = datetime.fromtimestamp(since, UTC)
    today = datetime.fromtimestamp(now, UTC).date()
    clock = at.strftime("%H:%M:%S") if at.date() == today else at.strftime("%Y-%m-%d %H:%M:%S")
    return f"since {clock} UTC, {duration_words(now - since)}"


def _candidates(details: Mapping[str, Any]) -> list[str]:
    info = str(details.get("complementary") or "")
    if not info.startswith("candidates:"):
        return []
    listing = info.removeprefix("candidates:").split(";", 1)[0]
    return [c.strip() for c in listing.split("|") if c.strip()]


def certainty_words(details: Mapping[str, Any], description: str = "") -> str:
    """``unique`` or ``one of N explanations`` from a failure's candidate explanations."""
    count = len(_candidates(details))
    if count == 0:
        found = _BEST_OF.search(description)
        count = int(found.group(1)) if found else 0
    if count == 0:
        return ""
    return "unique" if count == 1 else f"one of {count} explanations"


def _what_fails(entity: str, codes: str) -> str:
    names = [c.strip() for c in codes.split(",") if c.strip()]
    words = next((CODE_WORDS[n] for n in names if n in CODE_WORDS), DEFAULT_WORDS)
    return f"{entity} {words}"


def _evidence(details: Mapping[str, Any], cause: str) -> tuple[Evidence, ...]:
    out: list[Evidence] = []
    found = _FAILED.search(cause)
    if found:
        failed, total = int(found.group(1)), int(found.group(2))
        items = tuple(i.strip() for i in found.group(3).split(";") if i.strip())
        out.append(Evidence("Failed observations", items))
        out.append(Evidence("Held observations", (f"{total - failed} of {total} held",)))
    elif cause:
        out.append(Evidence("Failed observations",
                            tuple(i.strip() for i in cause.split(";") if i.strip())))
    candidates = _candidates(details)
    if len(candidates) > 1:
        out.append(Evidence("Alternative explanations", tuple(candidates[1:])))
    if details.get("consequence"):
        out.append(Evidence("Consequence", (str(details["consequence"]),)))
    info = str(details.get("complementary") or "")
    if "; engine" in info:
        out.append(Evidence("Diagnosed by", (info.split("; engine", 1)[1].strip(),)))
    if found and cause:
        out.append(Evidence("The engine's own words", (cause,)))
    return tuple(out)


def event_headline(kind: str, entity: str, text: str, details: Mapping[str, Any],
                   time: float | None = None) -> Headline:
    """The headline of one station event (the fields of ``store.Event``)."""
    if kind == "failure":
        description, _, cause = text.partition(": ")
        return Headline(
            _what_fails(entity or "the robot", str(details.get("proprietary_fault_code") or "")),
            "bad", time, certainty_words(details, description),
            str(details.get("operator_action") or ""),
            str(details.get("maintenance_action") or ""),
            _evidence(details, cause))
    if kind == "rectification":
        return Headline(f"{entity} works again", "good", time)
    if kind == "diagnosis":
        components = [str(c) for c in details.get("components") or []]
        if not components:
            return Headline("No failure diagnosed any more", "good", time)
        verb = "is" if len(components) == 1 else "are"
        return Headline(f"{', '.join(components)} {verb} diagnosed faulty", "bad", time)
    if kind == "exceedance":
        return Headline(text or f"{entity} is outside its limits", "warn", time)
    return Headline(text, "info", time)


def diagnosis_headlines(robot: str, components: Sequence[str], since: float | None,
                        failures: Mapping[str, tuple[str, Mapping[str, Any], float]],
                        degraded: Sequence[str] = (), *, stale: bool = False,
                        online: bool = True) -> list[Headline]:
    """The robot page's headlines, most urgent first: one per component diagnosed faulty
    (from its latest failure event: ``failures[name] = (text, details, time)``), else a
    line for degraded entities, else that all is well; a silent or stopped robot first."""
    out: list[Headline] = []
    if not online:
        out.append(Headline(f"{robot}'s black box has stopped: what is shown is its last state",
                            "warn"))
    elif stale:
        out.append(Headline(f"{robot} is silent: what is shown may be out of date", "warn"))
    for name in components:
        text, details, at = failures.get(name, ("", {}, since or 0.0))
        line = event_headline("failure", name, text, details, at if name in failures
                              else since)
        out.append(line)
    if not components:
        if degraded:
            verb = "shows" if len(degraded) == 1 else "show"
            out.append(Headline(f"No failure diagnosed; {', '.join(degraded)} {verb} "
                                "threshold exceedances", "warn"))
        elif online and not stale:
            out.append(Headline("Everything is working: no failure diagnosed", "good"))
    return out
