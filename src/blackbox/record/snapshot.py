"""The flight recorder: the last seconds of raw messages, written out when a fault happens.

The ring buffer lives on the pipeline's thread and must never slow observation down, so
:meth:`RingBuffer.offer` keeps a reference to the bytes the source already holds (no copy,
no decoding), decides per topic from a cache, and evicts from the front of a deque: O(1)
amortised. Writing a bag or MCAP file happens later on the recorder's writer thread.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path
from typing import NamedTuple

from blackbox.events import MessageArrival, TopicSchema


@dataclass(frozen=True, slots=True)
class SnapshotConfig:
    """``before``/``after``: seconds kept before a fault and recorded after it.

    ``max_bytes`` caps the ring buffer and each capture. ``keep_one_of`` maps a topic
    glob to N: only every N-th message of such topics is kept (images).
    """

    before: float = 10.0
    after: float = 5.0
    max_bytes: int = 64 * 1024 * 1024
    include: tuple[str, ...] = ("*",)
    exclude: tuple[str, ...] = ()
    keep_one_of: Mapping[str, int] = field(default_factory=dict)


class Held(NamedTuple):
    time: float
    topic: str
    publisher: str
    data: bytes | bytearray | memoryview


@dataclass(slots=True)
class Capture:
    """A snapshot being collected: the buffer at the trigger plus what follows."""

    trigger: float
    end: float
    name: str
    max_bytes: int
    messages: list[Held]
    size: int
    dropped: int = 0
    schemas: dict[str, TopicSchema | None] = field(default_factory=dict)
    failure_ids: list[int] = field(default_factory=list)

    def add(self, held: Held) -> None:
        n = len(held.data)
        if self.size + n > self.max_bytes:
            self.dropped += 1
            return
        self.messages.append(held)
        self.size += n


class RingBuffer:
    """Memory-bounded buffer of recent raw messages of the included topics."""

    def __init__(self, config: SnapshotConfig) -> None:
        self.config = config
        self._held: deque[Held] = deque()
        self._bytes = 0
        self._decisions: dict[str, int] = {}  # topic -> keep 1 of N; 0 = excluded
        self._counters: dict[str, int] = {}
        self._captures: list[Capture] = []
        self.offered = 0
        self.skipped_unavailable = 0
        self.skipped_oversize = 0

    @property
    def bytes(self) -> int:
        return self._bytes

    def __len__(self) -> int:
        return len(self._held)

    def _decide(self, topic: str) -> int:
        cfg = self.config
        if not any(fnmatchcase(topic, g) for g in cfg.include) or \
                any(fnmatchcase(topic, g) for g in cfg.exclude):
            keep = 0
        else:
            keep = 1
            for glob, n in cfg.keep_one_of.items():
                if fnmatchcase(topic, glob):
                    keep = max(1, int(n))
                    break
        self._decisions[topic] = keep
        return keep

    def offer(self, msg: MessageArrival) -> None:
        """Keep ``msg`` if its topic is included; never blocks, never copies its bytes."""
        topic = msg.topic
        keep = self._decisions.get(topic)
        if keep is None:
            keep = self._decide(topic)
        if keep == 0:
            return
        if keep > 1:
            n = self._counters.get(topic, 0)
            self._counters[topic] = n + 1
            if n % keep:
                return
        self.offered += 1
        data = msg.raw()
        if data is None:
            self.skipped_unavailable += 1
            return
        size = len(data)
        cap = self.config.max_bytes
        if size > cap:
            self.skipped_oversize += 1
            return
        held = Held(msg.time, topic, msg.publisher, data)
        held_q = self._held
        held_q.append(held)
        self._bytes += size
        horizon = msg.time - self.config.before
        while held_q and (self._bytes > cap or held_q[0].time < horizon):
            self._bytes -= len(held_q.popleft().data)
        for capture in self._captures:
            if held.time <= capture.end:
                capture.add(held)

    def active(self, time: float) -> Capture | None:
        """The capture collecting at ``time``, if any."""
        for capture in self._captures:
            if capture.trigger <= time <= capture.end:
                return capture
        return None

    def trigger(self, time: float, name: str) -> Capture:
        """Start a capture named ``name`` at ``time``, or join the one already collecting."""
        running = self.active(time)
        if running is not None:
            return running
        start = time - self.config.before
        before = [h for h in self._held if start <= h.time <= time]
        capture = Capture(time, time + self.config.after, name, self.config.max_bytes,
                          before, sum(len(h.data) for h in before))
        self._captures.append(capture)
        return capture

    def complete(self, now: float) -> list[Capture]:
        """Captures whose ``after`` window has passed at ``now``; they leave the buffer."""
        done = [c for c in self._captures if now >= c.end]
        if done:
            self._captures = [c for c in self._captures if now < c.end]
        return done

    def flush(self) -> list[Capture]:
        """Every open capture, for a clean shutdown."""
        done, self._captures = self._captures, []
        return done


@dataclass(frozen=True, slots=True)
class SnapshotFile:
    path: Path
    messages: int
    topics: tuple[str, ...]
    skipped_topics: tuple[str, ...]
    bytes: int


def _ros2_name(msgtype: str) -> str:
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


def _md5(schema: TopicSchema) -> str:
    if schema.md5sum:
        return schema.md5sum
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    name = _ros2_name(schema.type)
    store.register(get_types_from_msg(schema.definition, name))
    return store.generate_msgdef(name, ros_version=1)[1]


def write_bag(messages: Iterable[Held], schemas: Mapping[str, TopicSchema | None],
              path: Path) -> SnapshotFile:
    """A ROS 1 bag that ``rosbag info``/``rosbag play`` and rosbags read.

    Topics without a ROS 1 schema cannot go into a bag; they are named in
    ``skipped_topics``.
    """
    from rosbags.rosbag1 import Writer

    messages = sorted(messages, key=lambda h: h.time)
    path.parent.mkdir(parents=True, exist_ok=True)
    skipped: set[str] = set()
    written, nbytes = 0, 0
    with Writer(path) as writer:
        conns: dict[tuple[str, str], object] = {}
        for h in messages:
            schema = schemas.get(h.topic)
            if schema is None or schema.encoding != "ros1":
                skipped.add(h.topic)
                continue
            key = (h.topic, h.publisher)
            conn = conns.get(key)
            if conn is None:
                try:
                    md5 = _md5(schema)
                except Exception:
                    skipped.add(h.topic)
                    continue
                conn = writer.add_connection(h.topic, _ros2_name(schema.type),
                                             msgdef=schema.definition, md5sum=md5,
                                             callerid=h.publisher or None)
                conns[key] = conn
            writer.write(conn, max(0, int(h.time * 1e9)), bytes(h.data))  # type: ignore[arg-type]
            written += 1
            nbytes += len(h.data)
    topics = tuple(sorted({t for t, _ in conns}))
    return SnapshotFile(path, written, topics, tuple(sorted(skipped - set(topics))), nbytes)


def write_mcap(messages: Iterable[Held], schemas: Mapping[str, TopicSchema | None],
               path: Path) -> SnapshotFile:
    """An MCAP file: ROS 1 topics as ``ros1msg``/``ros1``, JSON topics with a JSON schema."""
    from mcap.writer import CompressionType, Writer

    messages = sorted(messages, key=lambda h: h.time)
    path.parent.mkdir(parents=True, exist_ok=True)
    skipped: set[str] = set()
    written, nbytes = 0, 0
    channels: dict[str, int] = {}
    with path.open("wb") as fh:
        writer = Writer(fh, compression=CompressionType.ZSTD)
        writer.start(profile="", library="blackbox")
        for seq, h in enumerate(messages):
            cid = channels.get(h.topic)
            if cid is None:
                schema = schemas.get(h.topic)
                if schema is None or schema.encoding not in ("ros1", "json"):
                    skipped.add(h.topic)
                    continue
                if schema.encoding == "ros1":
                    sid = writer.register_schema(schema.type, "ros1msg",
                                                 schema.definition.encode())
                    cid = writer.register_channel(h.topic, "ros1", sid)
                else:
                    sid = writer.register_schema(schema.type or h.topic, "jsonschema",
                                                 schema.definition.encode())
                    cid = writer.register_channel(h.topic, "json", sid)
                channels[h.topic] = cid
            stamp = max(0, int(h.time * 1e9))
            writer.add_message(cid, stamp, bytes(h.data), stamp, sequence=seq)
            written += 1
            nbytes += len(h.data)
        writer.finish()
    return SnapshotFile(path, written, tuple(sorted(channels)), tuple(sorted(skipped)), nbytes)


WRITERS: dict[str, Callable[[Iterable[Held], Mapping[str, TopicSchema | None], Path],
                            SnapshotFile]] = {"ros1": write_bag, "mcap": write_mcap}
SUFFIXES = {"ros1": ".bag", "mcap": ".mcap"}
