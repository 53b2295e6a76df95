"""What a station's reader would lose when it first meets a publisher through a live sample.

Zenoh's advanced subscriber hands over the first sample it receives from a publisher it has
not met yet at once, and from then on takes every older sample of that publisher for a
duplicate: when a history or heartbeat reply later brings them, they are dropped without a
word (zenoh-ext ``advanced_subscriber.rs``, ``handle_sample``). That happens whenever the
route from a robot to a station appears while the robot is publishing: a robot that
connects to a router the station already uses, two sites whose routers link up, a station
under load that hears the robot's first samples late. Whatever the robot cached before
(values, failures, states of entities that will not change again) would never arrive.

:class:`FirstContact` watches each sample's source (publisher id and sequence number).
The first sample of an unknown publisher with a sequence number above 0 means earlier
samples exist that this reader has not had: it holds that publisher's samples, asks the
publisher's cache for the earlier ones (the advanced publisher's own cache queryable, the
one heartbeat recovery asks) and releases the earlier ones and then the held ones, in the
order the robot wrote them, so states still end with the newest. A publisher whose cache
no longer holds them (more than ``CACHED_SAMPLES`` ago) or does not answer within
:data:`FETCH_TIMEOUT` costs only that wait.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import zenoh

FETCH_TIMEOUT = 5.0
"""Seconds a publisher's cache has to answer; its samples are held meanwhile."""
MAX_SOURCES = 100_000
"""Publishers remembered as met (the oldest forgotten beyond it; a forgotten one that is
met again costs one more query, which finds nothing new)."""

Source = tuple[str, int]
"""A publisher: its session's Zenoh id and its entity id in that session."""


@dataclass(slots=True)
class _Fetch:
    """One publisher's samples held while its earlier ones are fetched."""

    before: int
    """The sequence number of the first sample met; the fetch asks for those below."""
    held: list[bytes]
    deadline: float
    fetched: dict[int, bytes] = field(default_factory=dict)
    done: bool = False


def source_of(info: Any) -> Source:
    source = info.source_id
    return str(source.zid), int(source.eid)


class FirstContact:
    """Per reader: decides whether a sample passes now, and releases held ones later.

    Replies arrive on Zenoh's threads and only add to their own fetch (a dictionary
    assignment and a flag, each atomic under the interpreter lock); the reading thread
    alone moves samples on."""

    def __init__(self, session: Any, timeout: float = FETCH_TIMEOUT,
                 max_sources: int = MAX_SOURCES) -> None:
        self._session = session
        self.timeout = timeout
        self._max_sources = max_sources
        self._met: OrderedDict[Source, None] = OrderedDict()
        self._fetching: dict[Source, _Fetch] = {}
        self.fetches = 0
        """Publishers whose earlier samples were asked for."""
        self.recovered = 0
        """Samples got back that would otherwise have been lost."""

    def passes(self, sample: Any, payload: bytes) -> bool:
        """Whether ``sample`` goes to the reader's queue now; ``False`` when it is held."""
        info = sample.source_info
        if info is None:
            return True
        source = source_of(info)
        fetch = self._fetching.get(source)
        if fetch is not None:
            fetch.held.append(payload)
            return False
        if source in self._met:
            return True
        self._met[source] = None
        if len(self._met) > self._max_sources:
            self._met.popitem(last=False)
        sn = int(info.source_sn)
        if sn == 0:
            return True
        fetch = _Fetch(sn, [payload], time.monotonic() + self.timeout + 1.0)
        self._fetching[source] = fetch
        self._ask(str(sample.key_expr), source, fetch)
        return False

    def released(self) -> list[bytes]:
        """Payloads whose fetch has ended (answered, or timed out), in the order written."""
        if not self._fetching:
            return []
        now = time.monotonic()
        ended = [s for s, f in self._fetching.items() if f.done or now >= f.deadline]
        out: list[bytes] = []
        for source in ended:
            fetch = self._fetching.pop(source)
            fetched = dict(fetch.fetched)
            self.recovered += len(fetched)
            out.extend(fetched[sn] for sn in sorted(fetched))
            out.extend(fetch.held)
        return out

    def _ask(self, key: str, source: Source, fetch: _Fetch) -> None:
        zid, eid = source

        def reply(answer: Any) -> None:
            sample = answer.ok
            info = None if sample is None else sample.source_info
            if info is None or source_of(info) != source:
                return
            sn = int(info.source_sn)
            if sn < fetch.before:
                fetch.fetched[sn] = sample.payload.to_bytes()

        def finished() -> None:
            fetch.done = True

        self.fetches += 1
        try:
            self._session.get(f"{key}/@adv/*/{zid}/{eid}/**?_sn=..{fetch.before - 1}",
                              zenoh.handlers.Callback(reply, finished),
                              consolidation=zenoh.ConsolidationMode.NONE,
                              accept_replies=zenoh.ReplyKeyExpr.ANY,
                              timeout=self.timeout)
        except Exception:  # a closing session: release what is held, as before this fix
            fetch.done = True


__all__ = ["FETCH_TIMEOUT", "FirstContact"]
