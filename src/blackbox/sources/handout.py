"""What a live source's ``poll`` shares: handing out events in time order, never ahead of
the pipeline's clock, and saying so when its queue overflowed.

A live source collects events on background threads, stamped by wall time, so a batch can
arrive out of order and hold events stamped after the instant the pipeline asked up to.
Those are held back for the next poll, so the pipeline never sees the future.
"""

from __future__ import annotations

import threading
import time

from blackbox.events import Event
from blackbox.model import BlackBoxEvent


def wait_until(stop: threading.Event, until: float) -> None:
    """Block until wall time ``until``, or until ``stop`` is set (the source closing)."""
    delay = until - time.time()
    if delay > 0:
        stop.wait(delay)


def split_due(events: list[Event], until: float) -> tuple[list[Event], list[Event]]:
    """Sort ``events`` by time (stable, in place) and split them at ``until``: those
    stamped at or before it, to hand out now, and the rest, to hold for a later poll."""
    events.sort(key=_time_of)
    cut = len(events)
    while cut and events[cut - 1].time > until:
        cut -= 1
    return events[:cut], events[cut:]


def overflow_event(time: float, kind: str, dropped: int, source: str) -> BlackBoxEvent:
    """The event that reports ``dropped`` events lost because the source's queue was full."""
    return BlackBoxEvent(time, kind, f"dropped {dropped} events: the black box fell behind "
                         "the robot", source)


def _time_of(event: Event) -> float:
    return event.time
