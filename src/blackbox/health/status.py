"""Health status of characteristics, entities and the robot, with hysteresis.

The rules (documented for operators in ``docs/health.md``):

* A **characteristic** (one observer on one resource) is ``unknown`` until its first
  observation with a verdict, and again when it reports ``NOT_AVAILABLE`` or falls silent
  for ``stale_after`` evaluation intervals (the configured interval, else the last gap
  between its observations). It turns ``failing`` after ``raise_after``
  faulty observations in a row and returns to ``ok`` only after ``clear_after`` good ones
  in a row, so a signal wobbling around a threshold stays failing instead of flapping.
* An **entity** (a node) is UNKNOWN while all its characteristics are unknown;
  NOT_OPERATIONAL while the best diagnosis names it or when every known characteristic is
  failing; DEGRADED when some characteristic is failing; OPERATIONAL otherwise.
* The **robot** is UNKNOWN while every entity is; NOT_OPERATIONAL when every known entity
  is; OPERATIONAL when every known entity is; DEGRADED otherwise.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import IntEnum


class Health(IntEnum):
    """Same numbering as UCMS ``T_HealthStatus``."""

    OPERATIONAL = 0
    DEGRADED = 1
    NOT_OPERATIONAL = 2
    UNKNOWN = 3


UNKNOWN, OK, FAILING = "unknown", "ok", "failing"


@dataclass(frozen=True, slots=True)
class Hysteresis:
    raise_after: int = 1
    clear_after: int = 3
    stale_after: float = 3.0

    def __post_init__(self) -> None:
        if self.raise_after < 1 or self.clear_after < 1:
            raise ValueError("raise_after and clear_after must be >= 1")
        if self.stale_after <= 0:
            raise ValueError("stale_after must be > 0")


class CharacteristicStatus:
    """The latched verdict of one observer on one resource."""

    __slots__ = ("_bad_run", "_gap", "_good_run", "interval", "last_time", "rules", "state")

    def __init__(self, rules: Hysteresis, interval: float | None = None) -> None:
        self.rules = rules
        self.interval = interval
        self._gap = 1.0
        self.state = UNKNOWN
        self.last_time: float | None = None
        self._bad_run = 0
        self._good_run = 0

    def update(self, time: float, faulty: bool, available: bool = True) -> bool:
        """Take one verdict; True when the state changed."""
        before = self.state
        if self.last_time is not None and time > self.last_time:
            self._gap = time - self.last_time
        self.last_time = time
        if not available:
            self._bad_run = self._good_run = 0
            self.state = UNKNOWN
        elif faulty:
            self._bad_run += 1
            self._good_run = 0
            if self._bad_run >= self.rules.raise_after:
                self.state = FAILING
        else:
            self._good_run += 1
            self._bad_run = 0
            if self.state != FAILING or self._good_run >= self.rules.clear_after:
                self.state = OK
        return self.state != before

    def expire(self, now: float) -> bool:
        """Turn unknown when silent for too long; True when the state changed."""
        if self.state == UNKNOWN or self.last_time is None:
            return False
        interval = self.interval if self.interval is not None else self._gap
        if now - self.last_time > self.rules.stale_after * max(interval, 1e-3):
            self.state = UNKNOWN
            self._bad_run = self._good_run = 0
            return True
        return False


def entity_health(states: Iterable[str], diagnosed: bool) -> Health:
    known = [s for s in states if s != UNKNOWN]
    if diagnosed:
        return Health.NOT_OPERATIONAL
    if not known:
        return Health.UNKNOWN
    failing = sum(1 for s in known if s == FAILING)
    if failing == len(known):
        return Health.NOT_OPERATIONAL
    return Health.DEGRADED if failing else Health.OPERATIONAL


def robot_health(children: Iterable[Health]) -> Health:
    known = [h for h in children if h != Health.UNKNOWN]
    if not known:
        return Health.UNKNOWN
    if all(h == Health.OPERATIONAL for h in known):
        return Health.OPERATIONAL
    if all(h == Health.NOT_OPERATIONAL for h in known):
        return Health.NOT_OPERATIONAL
    return Health.DEGRADED
