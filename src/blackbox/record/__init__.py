"""The black box recorder: crash-safe health log, snapshots, retention and export."""

from blackbox.record.policy import FaultBoost, LoggingPolicy, PolicyRule
from blackbox.record.recorder import ConfigVersion, Recorder
from blackbox.record.snapshot import SnapshotConfig
from blackbox.record.store import LogEntry, StorageError, Store, StoreCorrupt

__all__ = [
    "ConfigVersion",
    "FaultBoost",
    "LogEntry",
    "LoggingPolicy",
    "PolicyRule",
    "Recorder",
    "SnapshotConfig",
    "StorageError",
    "Store",
    "StoreCorrupt",
]
