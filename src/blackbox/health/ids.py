"""Source ids that survive restarts.

A station keeps what it knows about a robot by UCMS source id, so the ids must not change
when the black box restarts or the observers are listed in another order. Every id is
derived from names only: the resource id from the robot id, the instance id from the kind
of object and its names (BLAKE2b, 31 bits, never 0 so that 0 stays the null reference).

Two different names hashing to the same instance id within one robot is possible (about
one in 10^6 for 100 objects); :class:`SourceIds` detects it and salts the later name, which
stays deterministic for the same configuration.
"""

from __future__ import annotations

import hashlib

from blackbox.health.types import T_IdentifierType

_MASK = 0x7FFF_FFFF


def stable_int(*parts: str) -> int:
    """A positive 31-bit integer from ``parts``, identical on every machine and run."""
    digest = hashlib.blake2b("\x1f".join(parts).encode("utf-8"), digest_size=8).digest()
    value = int.from_bytes(digest, "big") & _MASK
    return value or 1


def robot_resource_id(robot_id: str) -> int:
    return stable_int("robot", robot_id)


class SourceIds:
    """Hands out the identifiers of one robot's UCMS objects."""

    def __init__(self, robot_id: str) -> None:
        self.robot_id = robot_id
        self.resource_id = robot_resource_id(robot_id)
        self._by_name: dict[tuple[str, ...], int] = {}
        self._taken: dict[int, tuple[str, ...]] = {}

    def of(self, kind: str, *names: str) -> T_IdentifierType:
        """The id of object ``kind`` named ``names`` (for example ``"entity", "/usb_cam"``)."""
        name = (kind, *names)
        instance = self._by_name.get(name)
        if instance is None:
            salt = 0
            instance = stable_int(self.robot_id, *name)
            while instance in self._taken or instance == 0:
                salt += 1
                instance = stable_int(self.robot_id, *name, f"#{salt}")
            self._by_name[name] = instance
            self._taken[instance] = name
        return T_IdentifierType(self.resource_id, instance)

    def robot(self) -> T_IdentifierType:
        """The robot itself, the top monitored entity."""
        return self.of("entity", "")

    def name_of(self, ident: T_IdentifierType) -> tuple[str, ...] | None:
        if ident.A_resourceId != self.resource_id:
            return None
        return self._taken.get(ident.A_instanceId)
