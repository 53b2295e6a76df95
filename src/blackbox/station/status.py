"""One status for a robot, everywhere: its badge, its row in the entity tree, its fleet row.

The rule is the one the black box itself uses for the robot entity's UCMS health
(:func:`blackbox.health.status.robot_health`), applied by the station to the statuses it
holds, so the station and the robot's own UCMS report agree:

* ``UNKNOWN`` while the robot is silent (stale) or its black box said it stopped;
* else, over the known (not ``UNKNOWN``) statuses of its entities, the robot entity's own
  included: all ``OPERATIONAL`` gives ``OPERATIONAL``, all ``NOT_OPERATIONAL`` gives
  ``NOT_OPERATIONAL``, a mix gives ``DEGRADED``, none known gives ``UNKNOWN``.

A robot with one dead camera is therefore DEGRADED (it still drives), not NOT_OPERATIONAL;
which entity is down is what the headline and the tree say.
"""

from __future__ import annotations

from collections.abc import Iterable

from blackbox.health.status import Health, robot_health


def robot_status(entity_statuses: Iterable[str], *, stale: bool, online: bool) -> str:
    """The status shown for a robot (see the module's rule)."""
    if stale or not online:
        return "UNKNOWN"
    healths = [Health[s] if s in Health.__members__ else Health.UNKNOWN
               for s in entity_statuses]
    return robot_health(healths).name


ROBOT_STATUS_SQL = (
    "SELECT CASE WHEN count(*) = 0 THEN 'UNKNOWN' "
    "WHEN min(status) = max(status) AND min(status) IN ('OPERATIONAL', 'NOT_OPERATIONAL') "
    "THEN min(status) ELSE 'DEGRADED' END AS derived FROM entities "
    "WHERE resource_id = ? AND status IN ('OPERATIONAL', 'DEGRADED', 'NOT_OPERATIONAL')")
""":func:`robot_status` of a live robot over its stored entities (``?``: its resource id),
as SQL, so that the database derives it inside a write without a round trip to read the
entities (the same rule; ``tests/test_station_status_history.py`` checks that both agree)."""
