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
