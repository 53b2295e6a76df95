"""Event identities: a boot id and a sequence number, assigned once per event.

A station must tell two events apart even when they share a millisecond and an entity (a
fault and its recovery in one burst), and must tell one event apart from its copy (heard
live over DDS and again from the robot's log after a gap). Times cannot do either, so each
event a black box emits gets ``<boot>-<sequence>``: ``boot`` is random per start of the
black box, ``sequence`` counts that start's events from 1 without holes. Because the
sequence has no holes, a station that sees 7 after 5 knows it missed 6 and can fetch it.

The same event reaches two consumers: the UCMS mapper publishes it and the recorder logs
it. Both ask the :class:`EventLedger` for the identity of "this kind of event on this key
at this time"; the first to ask assigns, the second gets the same identity. Only events the
health model publishes consume sequence numbers (:meth:`EventLedger.assign`); the recorder
only looks up (:meth:`EventLedger.lookup`) unless it is the only consumer, so rows it logs
for its own reasons never open a hole a station would wait for.
"""

from __future__ import annotations

import os
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass

MEMORY = 8192
"""How many recent assignments the ledger remembers for look-ups (bounded memory)."""

_ID = re.compile(r"^([0-9a-f]{16})-([1-9][0-9]{0,18})$")


@dataclass(frozen=True, slots=True, order=True)
class EventId:
    """``boot`` (16 hex digits, random per start) and ``sequence`` (1, 2, ... per boot)."""

    boot: str
    sequence: int

    def __str__(self) -> str:
        return f"{self.boot}-{self.sequence}"

    @classmethod
    def parse(cls, text: str) -> EventId | None:
        """The identity written as ``<boot>-<sequence>``, or ``None`` if ``text`` is not one
        (identities come from the network and from logs: never trusted to be well formed)."""
        m = _ID.match(text) if isinstance(text, str) else None
        return cls(m.group(1), int(m.group(2))) if m else None


def new_boot() -> str:
    """A random boot id: 64 bits, so two starts of one robot never share one."""
    return os.urandom(8).hex()


class EventLedger:
    """Assigns and remembers event identities for one start of one black box.

    Thread-safe: the pipeline thread assigns while the DDS service thread (built-in tests)
    may map observations too.
    """

    def __init__(self, boot: str | None = None, memory: int = MEMORY) -> None:
        self.boot = boot or new_boot()
        if not re.fullmatch(r"[0-9a-f]{16}", self.boot):
            raise ValueError(f"boot id must be 16 lowercase hex digits, got {self.boot!r}")
        self.memory = max(16, memory)
        self._next = 1
        self._known: OrderedDict[tuple[str, str, int], EventId] = OrderedDict()
        self._at: dict[int, list[tuple[str, str, int]]] = {}
        self._lock = threading.Lock()

    @property
    def last(self) -> int:
        """The highest sequence number assigned so far (0: none)."""
        return self._next - 1

    def assign(self, kind: str, key: str, time: float) -> EventId:
        """The identity of ``kind`` on ``key`` at ``time``: new, or the one already given."""
        k = (kind, key, _nanoseconds(time))
        with self._lock:
            found = self._known.get(k)
            if found is not None:
                return found
            ident = EventId(self.boot, self._next)
            self._next += 1
            self._known[k] = ident
            self._at.setdefault(k[2], []).append(k)
            while len(self._known) > self.memory:
                old, _ = self._known.popitem(last=False)
                same_time = self._at[old[2]]
                same_time.remove(old)
                if not same_time:
                    del self._at[old[2]]
            return ident

    def lookup(self, kind: str, key: str, time: float) -> EventId | None:
        """The identity already assigned to ``kind`` on ``key`` at ``time``, if any."""
        with self._lock:
            return self._known.get((kind, key, _nanoseconds(time)))

    def at(self, time: float, kinds: tuple[str, ...]) -> list[tuple[str, str, EventId]]:
        """Every ``(kind, key, id)`` assigned at exactly ``time`` for one of ``kinds``, in
        the order assigned (the failures and recoveries one diagnosis caused)."""
        ns = _nanoseconds(time)
        with self._lock:
            return [(k, key, self._known[(k, key, t)]) for k, key, t in self._at.get(ns, ())
                    if k in kinds]


def _nanoseconds(t: float) -> int:
    return round(t * 1e9)
