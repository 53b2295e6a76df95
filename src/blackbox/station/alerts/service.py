"""The station's alerting at work: one thread follows the store, a few deliver.

The loop wakes on every committed change of the store (``wait_for_change``, so an alert
leaves within milliseconds of the flush that stored its event) and at least every
``tick`` seconds for time-driven work. Deliveries run on a small pool so one webhook that
hangs until its timeout does not hold up the others; each outbox row is in flight at most
once. A row that finally fails is reported as a station problem (the page's red banner),
logged on stderr and audited.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from blackbox.station.alerts.channels import Channel, Notification, Outcome, make_channel
from blackbox.station.alerts.db import AlertDB
from blackbox.station.alerts.engine import AlertEngine, Audit, _nobody
from blackbox.station.alerts.outbox import Outbox, OutboxEntry
from blackbox.station.alerts.rules import AlertConfig
from blackbox.station.database import Database
from blackbox.station.store import StationStore, StationStoreError

log = logging.getLogger("blackbox.station.alerts")


class AlertService:
    def __init__(self, store: StationStore, path: str | Path | Database, config: AlertConfig,
                 audit: Audit = _nobody, channels: Mapping[str, Channel] | None = None,
                 clock: Callable[[], float] = time.time, tick: float = 0.5,
                 workers: int = 4) -> None:
        self.store = store
        self.config = config
        self.clock = clock
        self.tick_interval = tick
        self.db = AlertDB(path)
        self.outbox = Outbox(self.db, config.delivery)
        self.engine = AlertEngine(store, self.db, config, self.outbox, audit)
        self.audit = audit
        self.channels: dict[str, Channel] = dict(channels) if channels is not None else {
            name: make_channel(spec) for name, spec in config.channels.items()}
        self._pool = ThreadPoolExecutor(max_workers=workers,
                                        thread_name_prefix="alert-delivery")
        self._busy: set[int] = set()
        self._busy_lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_tick = -float("inf")
        self._last_prune = -float("inf")
        self.delivered = 0
        self.failed_attempts = 0

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="alerts", daemon=True)
        self._thread.start()

    def wake(self) -> None:
        """Run the loop now (after a test notification, an acknowledgement)."""
        self._wake.set()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        self._pool.shutdown(wait=True, cancel_futures=True)
        self.db.close()

    def _run(self) -> None:
        seq = self.store.sequence
        while not self._stop.is_set():
            try:
                self.step()
            except StationStoreError as exc:  # the database is away: said once, retried
                self.store.report_problem("alerts", f"alerting waits for the database: {exc}")
            except Exception as exc:  # keep alerting alive; say what broke
                log.exception("alerting step failed")
                self.store.report_problem("alerts", f"alerting step failed: {exc}")
            wait = self.tick_interval
            with self._busy_lock:
                busy = frozenset(self._busy)
            try:
                upcoming = self.outbox.next_due(busy)
            except StationStoreError:  # the database is away: reported by step(), retried
                upcoming = None
            if upcoming is not None:
                wait = max(0.0, min(wait, upcoming - self.clock()))
            if self._wake.is_set():
                self._wake.clear()
                continue
            seq = self.store.wait_for_change(seq, wait)

    def step(self) -> None:
        """One round: new events, time-driven work, due deliveries (started, not awaited)."""
        now = self.clock()
        while self.engine.poll(now) >= 500:
            pass
        if now - self._last_tick >= self.tick_interval:  # not on every flush of a busy fleet
            self._last_tick = now
            self.engine.tick(now)
        if now - self._last_prune >= 3600.0:
            self._last_prune = now
            self.engine.prune(now)
        with self._busy_lock:
            busy = frozenset(self._busy)
        for entry in self.outbox.due(now, busy=busy):
            with self._busy_lock:
                self._busy.add(entry.id)
            self._pool.submit(self._deliver, entry)

    def _deliver(self, entry: OutboxEntry) -> None:
        try:
            channel = self.channels.get(entry.channel)
            if channel is None:
                outcome = Outcome(False, f"channel {entry.channel!r} is not configured")
            else:
                try:
                    outcome = channel.send(Notification(entry.id, entry.payload))
                except Exception as exc:  # a channel bug is a failed attempt, not a lost row
                    outcome = Outcome(False, f"{type(exc).__name__}: {exc}")
            state = self.outbox.record(entry.id, outcome, self.clock())
            if outcome.ok:
                self.delivered += 1
            else:
                self.failed_attempts += 1
            if state == "failed":
                message = (f"notification {entry.id} ({entry.purpose} of rule {entry.rule!r}) "
                           f"to {entry.channel} failed after {entry.attempts + 1} attempts: "
                           f"{outcome.detail}")
                log.error("%s", message)
                self.store.report_problem("alerts", message)
                self.audit("station", "alert.delivery", f"outbox {entry.id}", "failed",
                           message)
            elif state == "sent":
                self.audit("station", "alert.delivery", f"outbox {entry.id}", "ok",
                           f"{entry.purpose} to {entry.channel}: {outcome.detail}")
        finally:
            with self._busy_lock:
                self._busy.discard(entry.id)
            self._wake.set()
