"""Keeping the health log inside its disk budget, and predicting how long the budget lasts.

When the log grows past its budget, the least valuable data goes first: old periodic
samples are thinned (three of every four removed, so the oldest history gets coarser,
not shorter), then dropped oldest first; only then state changes and diagnoses; events,
failures and configurations last. Thinning keeps one in four rather than one in two on
purpose: SQLite merges a page with its neighbours only when it falls below a third full,
so only a heavy thinning actually frees pages.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from blackbox.record.store import KINDS, Store

_SAMPLE = KINDS["sample"]
_CHANGES = (KINDS["observation"], KINDS["exceedance"], KINDS["diagnosis"], KINDS["snapshot"])
_LAST = (KINDS["failure"], KINDS["blackbox_event"])


@dataclass(frozen=True, slots=True)
class RetentionReport:
    before_bytes: int
    after_bytes: int
    thinned: int = 0
    dropped: int = 0

    @property
    def acted(self) -> bool:
        return bool(self.thinned or self.dropped)


@dataclass(frozen=True, slots=True)
class Retention:
    """A disk budget for the log file. Acts above ``high`` x budget, stops below ``low``."""

    budget_bytes: int
    high: float = 0.95
    low: float = 0.85
    max_steps: int = 200

    def over(self, store: Store) -> bool:
        return store.used_bytes() > self.budget_bytes * self.high

    def enforce(self, store: Store) -> RetentionReport:
        before = store.used_bytes()
        if before <= self.budget_bytes * self.high:
            return RetentionReport(before, before)
        target = self.budget_bytes * self.low
        thinned = dropped = 0
        used = before
        for _ in range(self.max_steps):
            if used <= target:
                break
            n = self._thin_samples(store)
            if n:
                thinned += n
            else:
                n = self._drop_oldest(store)
                if not n:
                    break
                dropped += n
            store.reclaim()
            used = store.used_bytes()
        return RetentionReport(before, used, thinned, dropped)

    @staticmethod
    def _thin_samples(store: Store) -> int:
        """Thin the older half of not yet thinned samples to one in four per channel."""
        row = store.execute(
            "SELECT count(*), min(time), max(time) FROM entries "
            "WHERE kind = ? AND json_extract(payload, '$.thinned') IS NULL", (_SAMPLE,)
        ).fetchone()
        count, t0, t1 = row
        if count < 8:
            return 0
        cut = t0 + (t1 - t0) / 2
        store.execute("BEGIN IMMEDIATE")
        try:
            removed = store.delete_where(
                "id IN (SELECT id FROM (SELECT id, row_number() OVER "
                "(PARTITION BY channel ORDER BY time) AS n FROM entries "
                "WHERE kind = ? AND time < ? AND json_extract(payload, '$.thinned') IS NULL) "
                "WHERE n % 4 != 1)", (_SAMPLE, cut))
            store.execute(
                "UPDATE entries SET payload = json_set(payload, '$.thinned', 4) "
                "WHERE kind = ? AND time < ? AND json_extract(payload, '$.thinned') IS NULL",
                (_SAMPLE, cut))
            store.execute("COMMIT")
        except BaseException:
            store.execute("ROLLBACK")
            raise
        return removed

    @staticmethod
    def _drop_oldest(store: Store) -> int:
        """Delete the oldest tenth of the least valuable kind that still has entries."""
        latest_config = store.execute("SELECT max(id) FROM entries WHERE kind = ?",
                                      (KINDS["config"],)).fetchone()[0]
        for kinds in ((_SAMPLE,), _CHANGES, _LAST, (KINDS["config"],)):
            marks = ",".join("?" * len(kinds))
            n = store.execute(f"SELECT count(*) FROM entries WHERE kind IN ({marks}) "
                              "AND id IS NOT ?", (*kinds, latest_config)).fetchone()[0]
            if not n:
                continue
            take = max(1, n // 10)
            store.execute("BEGIN IMMEDIATE")
            try:
                removed = store.delete_where(
                    f"id IN (SELECT id FROM entries WHERE kind IN ({marks}) AND id IS NOT ? "
                    "ORDER BY time, id LIMIT ?)", (*kinds, latest_config, take))
                store.execute("COMMIT")
            except BaseException:
                store.execute("ROLLBACK")
                raise
            return removed
        return 0


def enforce_directory(directory: Path, budget_bytes: int) -> list[Path]:
    """Delete the oldest snapshot files until the directory fits ``budget_bytes``."""
    try:
        files = sorted((p for p in directory.iterdir() if p.is_file()),
                       key=lambda p: p.stat().st_mtime)
    except OSError:
        return []
    total = sum(p.stat().st_size for p in files)
    removed: list[Path] = []
    for p in files:
        if total <= budget_bytes:
            break
        size = p.stat().st_size
        try:
            p.unlink()
        except OSError:
            continue
        total -= size
        removed.append(p)
    return removed
