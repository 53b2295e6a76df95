"""Polling a live ROS 1 source in tests: keep every event until a condition holds."""

from __future__ import annotations

import time
from collections.abc import Callable

from blackbox.events import Event
from blackbox.sources.ros1 import Ros1Source


class Watch:
    """Polls a source in small steps, keeping every event, until a condition holds."""

    def __init__(self, source: Ros1Source) -> None:
        self.source = source
        self.events: list[Event] = []

    def until(self, cond: Callable[[], bool], timeout: float = 10.0) -> bool:
        deadline = time.time() + timeout
        while time.time() < deadline:
            self.events.extend(self.source.poll(time.time() + 0.1))
            if cond():
                return True
        return False
