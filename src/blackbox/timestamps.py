"""Times as people type them: seconds since the epoch or an ISO 8601 date-time (UTC unless
it says otherwise). One reading for every place a user gives a time (``blackbox log``, the
station's pages), so the same text means the same moment everywhere."""

from __future__ import annotations

from datetime import UTC, datetime


def parse_timestamp(text: str) -> float:
    """Seconds since the epoch of ``text``; ``ValueError`` when it is neither form."""
    try:
        return float(text)
    except ValueError:
        pass
    dt = datetime.fromisoformat(text)
    return (dt if dt.tzinfo else dt.replace(tzinfo=UTC)).timestamp()
