"""Each entity's and each robot's status over time, as the station saw it change.

The timeline draws what an operator saw: an entity DEGRADED for ten minutes is a yellow
span, which the failure and rectification events alone cannot tell (they only know red).
The station's store calls :func:`note` in the same transaction that writes an entity's
status, so a status change and its history commit together; a row is added only when the
status differs from the last one kept. The robot's own row (``instance_id`` :data:`ROBOT`)
is its derived status (:func:`blackbox.station.status.robot_status`, the one rule of the
badge), written whenever that changes.

The table is part of the versioned schema (version 3, :mod:`blackbox.station.schema`); its
SQL lives here, in the subset both engines accept (:mod:`blackbox.station.database`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from blackbox.station.database import Connection
from blackbox.station.status import ROBOT_STATUS_SQL

ROBOT = -1
"""The ``instance_id`` under which a robot's derived status is kept."""

@dataclass(frozen=True, slots=True)
class StatusTrack:
    """A robot's status changes in a window: ``before[iid]`` the status each entity had at
    the window's start (absent when none was kept yet), ``changes`` those inside it as
    ``(time, instance_id, status)``, oldest first."""

    before: Mapping[int, str]
    changes: Sequence[tuple[float, int, str]]

    def known(self) -> set[int]:
        """The entities (and :data:`ROBOT`) with any kept history up to the window's end."""
        return set(self.before) | {iid for _, iid, _ in self.changes}


_LAST = ("SELECT status FROM status_changes WHERE resource_id = ? AND instance_id = ? "
         "ORDER BY id DESC LIMIT 1")

_KEEP = ("INSERT INTO status_changes (resource_id, instance_id, time, status) "
         f"SELECT ?, ?, ?, ? WHERE coalesce(({_LAST}), '') <> ?")
"""Keep a status if it differs from the last one kept: decided by the database, so the
write needs no answer (pipelined on PostgreSQL, not a round trip per status)."""

_KEEP_ROBOT = ("INSERT INTO status_changes (resource_id, instance_id, time, status) "
               f"SELECT ?, {ROBOT}, ?, d.derived FROM ({ROBOT_STATUS_SQL}) AS d "
               f"WHERE coalesce(({_LAST}), '') <> d.derived")
"""Keep the robot's derived status (:data:`ROBOT_STATUS_SQL`) if it differs from the last
one kept."""


def last_statuses(db: Connection) -> dict[tuple[int, int], str]:
    """The last status kept of every entity (and robot): what a starting station knows
    without one read per entity when its fleet first reports (15,000 at 1,000 robots)."""
    return {(int(rid), int(iid)): str(status) for rid, iid, status in db.execute(
        "SELECT resource_id, instance_id, status FROM status_changes WHERE id IN "
        "(SELECT max(id) FROM status_changes GROUP BY resource_id, instance_id)")}


def note(db: Connection, resource_id: int, instance_id: int, status: str,
         t: float) -> None:
    """Keep ``status`` of an entity at ``t`` if it changed, and the robot's derived status
    over its entities (as stored, this one included) if that changed. Two statements whose
    conditions the database evaluates: nothing is read back, so on PostgreSQL they travel
    in the flush's pipeline (it was three reads, each a round trip, per status change:
    seconds of a flush at 500 robots, and the fault -> colour change waited on them)."""
    db.execute(_KEEP, (resource_id, instance_id, t, status, resource_id, instance_id, status))
    db.execute(_KEEP_ROBOT, (resource_id, t, resource_id, resource_id, ROBOT))


def read(db: Connection, resource_id: int, since: float, until: float) -> StatusTrack:
    before: dict[int, str] = {}
    for (iid,) in db.execute("SELECT DISTINCT instance_id FROM status_changes WHERE "
                             "resource_id = ? AND time < ?", (resource_id, since)).fetchall():
        row = db.execute("SELECT status FROM status_changes WHERE resource_id = ? AND "
                         "instance_id = ? AND time < ? ORDER BY time DESC, id DESC LIMIT 1",
                         (resource_id, iid, since)).fetchone()
        before[int(iid)] = str(row[0])
    changes = [(float(t), int(iid), str(status)) for t, iid, status in db.execute(
        "SELECT time, instance_id, status FROM status_changes WHERE resource_id = ? AND "
        "time >= ? AND time <= ? ORDER BY time, id", (resource_id, since, until))]
    return StatusTrack(before, changes)
