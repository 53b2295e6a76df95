"""The recorder's settings: typed, frozen, parsed from the native ``recorder:`` section here.

Everything the recorder can be told lives in :class:`RecorderSettings` (and its
:class:`SnapshotSettings`), so the recorder itself takes one object instead of a bag of
keywords, and the parsing (with the file, line and key path of every mistake) happens in
one place. Keys and defaults are documented in docs/recorder.md.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from blackbox.config.node import ConfigNode
from blackbox.record.policy import FaultBoost, LoggingPolicy, PolicyRule
from blackbox.record.snapshot import WRITERS, SnapshotConfig

DEFAULT_BUDGET = 1024**3
DEFAULT_PATH = "blackbox.db"

SnapshotFormat = Literal["ros1", "mcap"]
Durability = Literal["full", "normal"]
Overflow = Literal["drop", "block"]


@dataclass(frozen=True, slots=True)
class SnapshotSettings:
    """Raw-message snapshots around faults.

    ``ring`` is the ring buffer's configuration; ``format`` ``None`` means "the source's
    native format" (decided when the recorder is composed). ``directory`` ``None`` means
    ``<log>.snapshots`` beside the log. ``share`` of the disk budget is theirs.
    """

    ring: SnapshotConfig = field(default_factory=SnapshotConfig)
    format: SnapshotFormat | None = None
    directory: Path | None = None
    share: float = 0.25
    cooldown: float = 60.0
    retries: int = 3


@dataclass(frozen=True, slots=True)
class RecorderSettings:
    """Everything a :class:`~blackbox.record.recorder.Recorder` can be told.

    ``overflow`` is what happens when ``queue_limit`` rows wait for the disk: ``"drop"``
    (real time: the least valuable rows go first and the log counts them) or ``"block"``
    (a simulated clock: the pipeline waits, so it never outruns durable storage).
    ``replace_foreign`` allows starting a new log over a file that is not a health log
    (``--force``); without it such a file is refused, never renamed or overwritten.
    """

    path: Path = Path(DEFAULT_PATH)
    budget_bytes: int = DEFAULT_BUDGET
    commit_interval: float = 1.0
    commit_rows: int = 10_000
    durability: Durability = "full"
    queue_limit: int = 200_000
    overflow: Overflow = "drop"
    retention_interval: float = 10.0
    retry_interval: float = 2.0
    policy: LoggingPolicy = field(default_factory=LoggingPolicy)
    snapshot: SnapshotSettings | None = field(default_factory=SnapshotSettings)
    replace_foreign: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))
        if self.commit_interval <= 0 or self.queue_limit < 1 or self.commit_rows < 1:
            raise ValueError("commit_interval, commit_rows and queue_limit must be positive")
        if self.overflow not in ("drop", "block"):
            raise ValueError("overflow must be 'drop' or 'block'")
        snap = self.snapshot
        if snap is not None and snap.format is not None and snap.format not in WRITERS:
            raise ValueError(f"snapshot format must be one of {', '.join(WRITERS)}")

    @property
    def snapshot_dir(self) -> Path:
        snap = self.snapshot
        if snap is not None and snap.directory is not None:
            return snap.directory
        return self.path.with_name(self.path.name + ".snapshots")

    @property
    def snapshot_budget(self) -> int:
        return int(self.budget_bytes * self.snapshot.share) if self.snapshot else 0

    def replace(self, **changes: object) -> RecorderSettings:
        """A copy with ``changes`` (``dataclasses.replace``), for the command line's overrides."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]

    @classmethod
    def from_config(cls, section: ConfigNode | None, base_dir: Path) -> RecorderSettings:
        """The settings of a native ``recorder:`` section; paths relative to ``base_dir``."""
        return recorder_settings(section, base_dir)


# ---- the native `recorder:` section ------------------------------------------------------------

_UNITS = {"b": 1, "kb": 1000, "mb": 1000**2, "gb": 1000**3, "tb": 1000**4,
          "kib": 1024, "mib": 1024**2, "gib": 1024**3, "tib": 1024**4}


def parse_size(text: str) -> int:
    """``"1 GB"``, ``"512MiB"``, ``"1000000"`` -> bytes."""
    s = text.strip().lower().replace("_", "")
    num = s.rstrip("abcdefghijklmnopqrstuvwxyz").strip()
    unit = s[len(num):].strip() or "b"
    if unit not in _UNITS:
        raise ValueError(f"unknown size unit {unit!r}; use B, KB, MB, GB, TB, KiB, MiB, GiB")
    try:
        value = float(num)
    except ValueError:
        raise ValueError(f"not a size: {text!r}") from None
    if value < 0:
        raise ValueError(f"a size cannot be negative: {text!r}")
    return int(value * _UNITS[unit])


def _size(node: ConfigNode) -> int:
    raw = node.raw
    if isinstance(raw, int) and not isinstance(raw, bool):
        return node.int(min=1)
    if isinstance(raw, str):
        try:
            return parse_size(raw)
        except ValueError as exc:
            raise node.error(str(exc)) from None
    raise node.error("expected a size in bytes or a text like '1 GB'")


def _boost(node: ConfigNode | None, default: FaultBoost | None) -> FaultBoost | None:
    if node is None:
        return default
    if not node.is_map and node.raw is False:
        return None
    node.check_keys(["interval", "duration", "snapshot"])
    base = default or FaultBoost()
    return FaultBoost(
        interval=node["interval"].float(min=0, min_exclusive=True) if node.get("interval")
        else base.interval,
        duration=node["duration"].float(min=0) if node.get("duration") else base.duration,
        snapshot=node["snapshot"].bool() if node.get("snapshot") is not None else base.snapshot,
    )


def _rule(node: ConfigNode, base: PolicyRule, matching: bool) -> PolicyRule:
    keys = ["interval", "on_fault", "states"] + (["entity", "characteristic"] if matching else [])
    node.check_keys(keys)
    interval: float | None = base.interval
    if "interval" in node:
        iv = node.get("interval")
        interval = None if iv is None or (not iv.is_map and iv.raw is False) else \
            iv.float(min=0, min_exclusive=True)
    states: dict[str, float] = dict(base.states)
    if node.get("states") is not None:
        for key, child in node["states"].items():
            states[key] = child.float(min=0, min_exclusive=True)
    return PolicyRule(
        entity=node["entity"].str() if matching and node.get("entity") else "*",
        characteristic=node["characteristic"].str() if matching and node.get("characteristic")
        else "*",
        interval=interval,
        on_fault=_boost(node.get("on_fault"), base.on_fault) if "on_fault" in node
        else base.on_fault,
        states=states,
    )


def policy_from_config(node: ConfigNode | None) -> LoggingPolicy:
    if node is None:
        return LoggingPolicy()
    node.check_keys(["interval", "on_fault", "states", "rules"])
    default = _rule(ConfigNode.mapping({k: v for k, v in node.items() if k != "rules"}, node),
                    PolicyRule(), matching=False)
    rules: list[PolicyRule] = []
    if node.get("rules") is not None:
        for item in node["rules"].list():
            if "entity" not in item and "characteristic" not in item:
                raise item.error("a rule needs 'entity' or 'characteristic' (globs) to match")
            rules.append(_rule(item, default, matching=True))
    return LoggingPolicy(tuple(rules), default)


def _ring(node: ConfigNode) -> SnapshotConfig:
    base = SnapshotConfig()
    keep: dict[str, int] = {}
    if node.get("keep_one_of") is not None:
        for topic, child in node["keep_one_of"].items():
            keep[topic] = child.int(min=1)
    return SnapshotConfig(
        before=node["before"].float(min=0) if node.get("before") else base.before,
        after=node["after"].float(min=0) if node.get("after") else base.after,
        max_bytes=_size(node["max_bytes"]) if node.get("max_bytes") else base.max_bytes,
        include=node["include"].str_list() if node.get("include") else base.include,
        exclude=node["exclude"].str_list() if node.get("exclude") else base.exclude,
        keep_one_of=keep,
    )


def snapshot_settings(node: ConfigNode | None, base_dir: Path) -> SnapshotSettings | None:
    """The ``recorder.snapshot`` section; ``None`` when snapshots are switched off."""
    if node is None:
        return SnapshotSettings()
    if not node.is_map:
        if node.raw is False:
            return None
        raise node.error("expected a mapping or false")
    node.check_keys(["enabled", "format", "before", "after", "max_bytes", "include", "exclude",
                     "keep_one_of", "directory", "share", "cooldown"])
    if node.get("enabled") is not None and not node["enabled"].bool():
        return None
    base = SnapshotSettings()
    fmt: SnapshotFormat | None = None
    if node.get("format"):
        fmt = "mcap" if node["format"].str(list(WRITERS)) == "mcap" else "ros1"
    return SnapshotSettings(
        ring=_ring(node),
        format=fmt,
        directory=base_dir / node["directory"].str() if node.get("directory") else None,
        share=node["share"].float(min=0, max=0.9) if node.get("share") else base.share,
        cooldown=node["cooldown"].float(min=0) if node.get("cooldown") is not None
        else base.cooldown,
    )


def recorder_settings(section: ConfigNode | None, base_dir: Path) -> RecorderSettings:
    """The settings of a native ``recorder:`` section (``None``: all defaults)."""
    default_path = base_dir / DEFAULT_PATH
    if section is None:
        return RecorderSettings(path=default_path)
    section.check_keys(["path", "budget", "commit_interval", "durability", "queue_limit",
                        "policy", "snapshot"])
    base = RecorderSettings()
    durability: Durability = base.durability
    if section.get("durability"):
        durability = "normal" if section["durability"].str(["full", "normal"]) == "normal" \
            else "full"
    return RecorderSettings(
        path=base_dir / section["path"].str() if section.get("path") else default_path,
        budget_bytes=_size(section["budget"]) if section.get("budget") else base.budget_bytes,
        commit_interval=section["commit_interval"].float(min=0.01, max=60)
        if section.get("commit_interval") else base.commit_interval,
        durability=durability,
        queue_limit=section["queue_limit"].int(min=100) if section.get("queue_limit")
        else base.queue_limit,
        policy=policy_from_config(section.get("policy")),
        snapshot=snapshot_settings(section.get("snapshot"), base_dir),
    )
