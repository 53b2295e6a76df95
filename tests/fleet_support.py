"""A station database holding a large fleet, written through the store's own write API
(what the follower stores), for the fleet page's tests and ``benchmarks/fleet_page.py``."""

from __future__ import annotations

import time
from collections.abc import Mapping

from blackbox.health.ids import robot_resource_id
from blackbox.station.store import StationStore

SITES: Mapping[str, tuple[str, ...]] = {"depot-a": ("tug-0[01]*",), "ward-b": ("tug-0[23]*",),
                                        "harbour": ("tug-0[4-9]*",)}
"""Robot name globs per site, as an alert rules file's ``sites:`` names them."""
ENTITIES = ("/usb_cam", "/usb_cam/image_raw", "/audio_capture", "/audio",
            "/signal_generator", "/signal")


def robot_name(i: int) -> str:
    return f"tug-{i:04d}"


def status_of(i: int) -> str:
    """Every 50th robot not operational, every 10th degraded, every 25th silent
    (UNKNOWN), the rest operational."""
    if i % 50 == 7:
        return "NOT_OPERATIONAL"
    if i % 10 == 3:
        return "DEGRADED"
    if i % 25 == 11:
        return "UNKNOWN"
    return "OPERATIONAL"


def fill_fleet(store: StationStore, robots: int, now: float | None = None) -> None:
    """``robots`` robots of the thesis robot's shape (the robot, 3 nodes, 3 topics), with
    the statuses :func:`status_of` gives; silent ones last heard an hour ago."""
    now = time.time() if now is None else now
    for i in range(robots):
        name = robot_name(i)
        rid = robot_resource_id(name)
        status = status_of(i)
        store.heard(rid, now - 3600 if status == "UNKNOWN" else now)
        store.put_robot_id(rid, name)
        robot_status = "OPERATIONAL" if status == "UNKNOWN" else status
        store.put_entity(rid, 1, name=name, kind="robot", status=robot_status)
        for j, entity in enumerate(ENTITIES, start=2):
            faulty = j == 2 and robot_status != "OPERATIONAL"
            store.put_entity(rid, j, name=entity, parent=1,
                             kind="topic" if entity.count("/") > 1 or j % 2 else "node",
                             status=robot_status if faulty else "OPERATIONAL")
        if robot_status == "NOT_OPERATIONAL":
            for j in range(2, 2 + len(ENTITIES)):
                store.put_entity(rid, j, status="NOT_OPERATIONAL")
        if robot_status != "OPERATIONAL":
            store.put_diagnosis(rid, ["/usb_cam"], now - 60)
            store.add_event(rid, now - 60, "failure", dedup=f"f-{i}", entity="/usb_cam",
                            text="/usb_cam diagnosed faulty")
    assert store.flush(force=True), "the fleet could not be written"
