"""The health timeline of a robot as the station's pages draw it: the lanes of a window read
from the store (the kept status history where there is one, else the events), drawn by
:mod:`blackbox.station.timeline`. The robot page, the entity page and the timeline file
share it."""

from __future__ import annotations

import time

from blackbox.station.status_history import ROBOT
from blackbox.station.store import StationStore
from blackbox.station.timeline import ZOOMS, Happening, Lane, Recorded, build, svg


def timeline_of(store: StationStore, r: str, zoom: str, only: str = "",
                links: bool = True) -> str:
    """The robot's health timeline over the last ``zoom`` (see station/timeline.py):
    every entity, or ``only`` that one (with the robot's lane)."""
    end = time.time()
    start = end - ZOOMS[zoom if zoom in ZOOMS else "1h"]
    return svg(timeline_lanes(store, r, start, end, only), start, end,
               robot_ref=r if links else "")


def timeline_lanes(store: StationStore, r: str, start: float, end: float,
                   only: str = "") -> list[Lane]:
    """The lanes of ``[start, end]``: from the kept status history where the station has
    one (station/status_history.py), else from failure and rectification events."""
    entities = [e for e in store.entities(r) if e.kind != "robot"
                and (not only or e.name == only)]
    names = [e.name for e in entities]
    kinds = ["failure", "rectification", "exceedance"]
    found = store.events(r, kinds=kinds, since=start, until=end, limit=1000).events
    track = store.status_track(r, start, end)
    kept = track.known()
    recorded = {e.name: Recorded(track.before.get(e.instance_id, "UNKNOWN"),
                                 [(t, status) for t, iid, status in track.changes
                                  if iid == e.instance_id])
                for e in entities if e.instance_id in kept}
    robot_recorded = Recorded(track.before.get(ROBOT, "UNKNOWN"),
                              [(t, status) for t, iid, status in track.changes
                               if iid == ROBOT]) if ROBOT in kept else None
    before = {}
    for name in names:
        if name in recorded:
            continue
        last = store.events(r, entity=name, kinds=["failure", "rectification"],
                            until=start, limit=1).events
        if last:
            before[name] = "NOT_OPERATIONAL" if last[0].kind == "failure" else \
                "OPERATIONAL"
    return build(store.robot(r).name, names,
                 [Happening(e.time, e.kind, e.entity, e.acknowledged_at) for e in found],
                 start, end, before, recorded, robot_recorded)
