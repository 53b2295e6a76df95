"""How pages write times, ages and values: the Jinja2 filters every template uses."""

from __future__ import annotations

import time
from datetime import UTC, datetime

from fastapi import HTTPException

from blackbox.timestamps import parse_timestamp


def fmt_time(t: float | None) -> str:
    if t is None:
        return "never"
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def fmt_clock(t: float | None) -> str:
    """A table's time: the clock for today (what a glance needs), the date too otherwise;
    the full time is in the cell's title."""
    if t is None:
        return "never"
    at = datetime.fromtimestamp(t, UTC)
    today = at.date() == datetime.now(UTC).date()
    return at.strftime("%H:%M:%S" if today else "%Y-%m-%d %H:%M")


def fmt_ago(t: float | None) -> str:
    if t is None:
        return "never"
    age = max(0.0, time.time() - t)
    if age < 90:
        return f"{age:.0f} s ago"
    if age < 5400:
        return f"{age / 60:.0f} min ago"
    return f"{age / 3600:.1f} h ago"


def fmt_value(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


def parse_time(text: str | None) -> float | None:
    """``YYYY-MM-DDTHH:MM[:SS]`` (UTC, as a datetime-local input sends it) or epoch seconds."""
    if not text:
        return None
    text = text.strip()
    try:
        return parse_timestamp(text)
    except ValueError:
        raise HTTPException(400, f"not a time: {text[:40]!r} (use YYYY-MM-DDTHH:MM:SS, UTC)")\
            from None


def robot_ref(robot_id: str, resource_id: int) -> str:
    """How pages name a robot in URLs: its id, else ``#<resource id>``."""
    return robot_id or f"#{resource_id}"
