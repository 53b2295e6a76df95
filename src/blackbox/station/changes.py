"""The change feed: what each committed write changed, for Server-Sent Events without polling.

A store calls :meth:`ChangeFeed.notify` after each committed flush; the web application
either waits on :meth:`ChangeFeed.wait_for_change`, holds a bounded :class:`Subscription`
(a slow reader loses the oldest changes and is told to reload), or registers a listener.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Change:
    """What one committed flush changed: ``seq`` increases by one per flush; ``robots``
    are resource ids; ``topics`` name what changed (``fleet``, ``entities``,
    ``characteristics``, ``events``, ``logs``, ``ibit``, ``problems``). ``overflow`` is set
    on the first change a slow subscriber sees after changes were dropped for it: reload."""

    seq: int
    time: float
    robots: frozenset[int]
    topics: frozenset[str]
    overflow: bool = False


class Subscription:
    """A bounded, thread-safe queue of :class:`Change` for one subscriber.

    ``get(timeout)`` returns the next change or ``None`` on timeout. When the subscriber
    falls ``maxsize`` changes behind, older changes are dropped and the next one returned
    has ``overflow`` set. ``close()`` (or leaving a ``with`` block) unsubscribes.
    """

    def __init__(self, feed: ChangeFeed, maxsize: int) -> None:
        self._feed = feed
        self._queue: queue.Queue[Change] = queue.Queue(maxsize=max(1, maxsize))
        self._overflow = False
        self._lock = threading.Lock()

    def _offer(self, change: Change) -> None:
        with self._lock:
            if self._overflow:
                change = Change(change.seq, change.time, change.robots, change.topics, True)
            try:
                self._queue.put_nowait(change)
                self._overflow = False
            except queue.Full:
                with contextlib.suppress(queue.Empty):
                    self._queue.get_nowait()
                self._queue.put_nowait(Change(change.seq, change.time, change.robots,
                                              change.topics, True))

    def get(self, timeout: float | None = None) -> Change | None:
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        self._feed._unsubscribe(self)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ChangeFeed:
    """Sequence numbers, subscribers and listeners of one store (thread-safe).

    ``on_listener_error`` is told when a listener raises (a broken listener must not stop
    ingestion: the store reports it as a problem)."""

    def __init__(self, clock: Callable[[], float] = time.time,
                 on_listener_error: Callable[[Exception], None] | None = None) -> None:
        self.clock = clock
        self.on_listener_error = on_listener_error
        self._subscribers: list[Subscription] = []
        self._listeners: list[Callable[[Change], None]] = []
        self._lock = threading.Lock()
        self._seq = 0
        self._seq_cond = threading.Condition()

    @property
    def sequence(self) -> int:
        """Number of committed flushes that changed something (increases monotonically)."""
        return self._seq

    def wait_for_change(self, after: int, timeout: float) -> int:
        """Block until :attr:`sequence` exceeds ``after`` or ``timeout`` passes; returns it."""
        with self._seq_cond:
            self._seq_cond.wait_for(lambda: self._seq > after, timeout=max(0.0, timeout))
            return self._seq

    def subscribe(self, maxsize: int = 256) -> Subscription:
        """A new :class:`Subscription` receiving every later :class:`Change`."""
        sub = Subscription(self, maxsize)
        with self._lock:
            self._subscribers.append(sub)
        return sub

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._lock, contextlib.suppress(ValueError):
            self._subscribers.remove(sub)

    def add_listener(self, callback: Callable[[Change], None]) -> Callable[[], None]:
        """Call ``callback(change)`` after each committed flush, on the writing thread (it
        must be quick: e.g. ``loop.call_soon_threadsafe``). Returns a function removing it."""
        with self._lock:
            self._listeners.append(callback)

        def remove() -> None:
            with self._lock, contextlib.suppress(ValueError):
                self._listeners.remove(callback)
        return remove

    def notify(self, robots: frozenset[int], topics: frozenset[str]) -> None:
        with self._seq_cond:
            self._seq += 1
            change = Change(self._seq, self.clock(), robots, topics)
            self._seq_cond.notify_all()
        with self._lock:
            subscribers = list(self._subscribers)
            listeners = list(self._listeners)
        for sub in subscribers:
            sub._offer(change)
        for callback in listeners:
            try:
                callback(change)
            except Exception as exc:  # a broken listener must not stop ingestion
                if self.on_listener_error is not None:
                    self.on_listener_error(exc)
