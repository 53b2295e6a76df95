"""Two black boxes claiming one robot id at once, told apart by their boot ids.

Every event a black box publishes carries ``<boot>-<sequence>``; the boot id is new at every
start. One robot's boots follow each other: once a new boot speaks, the old one is gone. Two
black boxes configured with the same robot id (a copied configuration, a spare unit) speak
at the same time, so their boots *interleave*: A, B, A. The station keeps the events of both
(their identities differ, so neither overwrites the other) and tells the operator, once per
pair, which robot id is shared.

Pure bookkeeping; the follower's thread calls it for live events only (a log backfill of an
earlier boot after a restart is not an interleaving).
"""

from __future__ import annotations

from collections.abc import Callable

KEPT_BOOTS = 8
"""Boots remembered per robot id (the last ones heard live)."""


class BootWatch:
    """Per robot id, the order its boots were heard live in; ``report(source, message)``
    when two interleave."""

    def __init__(self, report: Callable[[str, str], None]) -> None:
        self._report = report
        self._boots: dict[str, list[str]] = {}
        self.clashes: dict[str, frozenset[str]] = {}
        """Robot id -> the boots found interleaving (the latest pair)."""

    def see(self, robot: str, boot: str) -> bool:
        """Note a live event of ``boot`` under ``robot``; ``True`` when it interleaves."""
        boots = self._boots.setdefault(robot, [])
        if boots and boots[-1] == boot:
            return False
        clash = boot in boots
        if clash:
            other = boots[-1]
            boots.remove(boot)
            pair = frozenset({boot, other})
            if self.clashes.get(robot) != pair:
                self.clashes[robot] = pair
                a, b = sorted(pair)
                self._report(f"robot id {robot}",
                             f"{robot}: two black boxes use this robot id at once (boots {a} "
                             f"and {b} interleave); the events of both are kept; give one "
                             "of them its own robot id")
        boots.append(boot)
        del boots[:-KEPT_BOOTS]
        return clash
