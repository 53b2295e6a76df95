"""``BagSource``: a recording replayed as the events a live robot would have produced.

The clock is the recording's: every event carries the time its message was recorded
(seconds since the epoch), so observations and diagnoses of a replay line up with those of
the live run. On a simulated clock ``poll`` returns at once (as fast as the file reads);
in real time it waits until the wall clock, scaled by ``rate``, reaches ``until``.

What a recording knows of the graph: topics, their types and, where the file records them
(ROS 1 bags' ``callerid``, MCAP ``callerid`` metadata), their publishers. A
``GraphSnapshot`` is emitted when a (topic, publisher) pair sends its first message. A
topic without a recorded publisher gets the placeholder :func:`placeholder_publisher`.
Node liveness, pids, CPU and memory are not in a bag: the graph lists no nodes and no
resource or network samples are produced.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Literal

from blackbox.config.node import ConfigError
from blackbox.events import (
    Event,
    GraphSnapshot,
    Interest,
    MessageArrival,
    TopicInfo,
    TopicSchema,
)
from blackbox.model import BlackBoxEvent
from blackbox.sources.bag.decode import Decoder, UnknownBagType, decoder_for, schema_of
from blackbox.sources.bag.mcapfile import McapScanner
from blackbox.sources.bag.records import BagCorrupt, Item, RecordedMessage, RecordedTopic
from blackbox.sources.bag.ros1bag import MAGIC as ROS1_MAGIC
from blackbox.sources.bag.ros1bag import Ros1BagScanner
from blackbox.sources.bag.rosbag2 import Rosbag2Scanner
from blackbox.sources.base import SOURCES, Capabilities, SourceKind, SourceOptions

log = logging.getLogger("blackbox.sources.bag")

BAG_CAPABILITIES = Capabilities(simulated_clock=True, replay=True)
MCAP_MAGIC = b"\x89MCAP0\r\n"
REORDER_NS = 500_000_000
"""Read-ahead past ``until``: messages up to this much out of file order are put back in
time order (multi-threaded recorders write near-simultaneous messages in any order)."""

Scanner = Ros1BagScanner | McapScanner | Rosbag2Scanner


def placeholder_publisher(topic: str) -> str:
    """The publisher named for a topic whose file records none: ``(publisher of TOPIC)``."""
    return f"(publisher of {topic})"


def open_scanner(path: Path) -> tuple[Scanner, Literal["ros1", "mcap"]]:
    """The reader for ``path`` (by content, not by name) and the snapshot format matching it.

    Raises ``ConfigError`` for a path that is none of the three kinds.
    """
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise ConfigError(f"{path} is a directory without metadata.yaml, not a rosbag2 "
                              "bag", "--source")
        try:
            return Rosbag2Scanner(path), "mcap"
        except BagCorrupt as exc:
            raise ConfigError(str(exc), "--source") from None
    try:
        with path.open("rb") as fh:
            head = fh.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise ConfigError(f"cannot read {path}: {exc.strerror or exc}", "--source") from None
    if head.startswith(ROS1_MAGIC[:len(head)]) and head:
        return Ros1BagScanner(path), "ros1"
    if head == MCAP_MAGIC:
        return McapScanner(path), "mcap"
    if (path.parent / "metadata.yaml").is_file():
        return open_scanner(path.parent)
    raise ConfigError(f"{path} is neither a ROS 1 bag, an MCAP file nor a rosbag2 directory "
                      f"(starts with {head!r})", "--source")


class BagSource:
    """A ROS 1 bag, rosbag2 directory or MCAP file replayed as source events."""

    def __init__(self, path: Path, *, realtime: bool = False, rate: float = 1.0,
                 start_time: float | None = None) -> None:
        if not rate > 0:
            raise ValueError(f"rate must be positive, got {rate!r}")
        self.path = path
        self.name = f"bag:{path}"
        self.realtime = realtime
        self.rate = rate
        self._scanner, fmt = open_scanner(path)
        self.capabilities = Capabilities(simulated_clock=True, replay=True,
                                         snapshot_format=fmt)
        self._items: Iterator[Item] | None = self._scanner.scan()
        # Read-ahead in file order; sorted by time (stable) before handing out when a
        # message came out of order (rare: timsort on nearly sorted data is linear).
        self._pending: deque[tuple[int, RecordedMessage | BlackBoxEvent]] = deque()
        self._unsorted = False
        self._read_ns = -1  # time of the last message read from the file
        self._first_ns: int | None = None
        self._start_ns = None if start_time is None else round(start_time * 1e9)
        self.messages_read = 0
        self.out_of_order = 0
        self.corruption: BagCorrupt | None = None
        self._fill(self._start_ns if self._start_ns is not None else 0, first_only=True)
        origin = self._start_ns if self._start_ns is not None else self._first_ns
        self._origin = (origin or 0) / 1e9
        self._clock = self._origin
        self._emitted_ns = 0
        self._wall_origin = 0.0
        self._interest = Interest()
        self._wanted: frozenset[str] = frozenset()
        self._topics: dict[str, RecordedTopic] = {}
        self._shown: dict[str, list[str]] = {}
        self._decoders: dict[RecordedTopic, Decoder | None] = {}
        self._started = False

    # ---- Source protocol -------------------------------------------------------------------

    def start(self, interest: Interest) -> None:
        if self._started:
            raise RuntimeError(f"{self.name} started twice")
        self._started = True
        self._interest = interest
        self._wanted = interest.topics | interest.decoded
        self._wall_origin = time.monotonic()

    def now(self) -> float:
        if self.realtime and self._started:
            return self._origin + (time.monotonic() - self._wall_origin) * self.rate
        return self._clock

    def poll(self, until: float) -> list[Event]:
        if not self._started:
            raise RuntimeError(f"{self.name}: call start() before poll()")
        if self.realtime:
            while (wait := (until - self.now()) / self.rate) > 0:
                time.sleep(wait)
        until_ns = int(until * 1e9)
        self._fill(until_ns + REORDER_NS)
        pending = self._pending
        if self._unsorted:
            self._pending = pending = deque(sorted(pending, key=_stamp))
            self._unsorted = False
        events: list[Event] = []
        emit = self._emit
        while pending and pending[0][0] <= until_ns:
            stamp, item = pending.popleft()
            if type(item) is RecordedMessage:
                emit(stamp, item, events)
            else:
                events.append(item)  # type: ignore[arg-type]
        self._clock = max(self._clock, until)
        return events

    def exhausted(self) -> bool:
        return self._items is None and not self._pending

    def schema(self, topic: str) -> TopicSchema | None:
        recorded = self._topics.get(topic)
        return schema_of(recorded) if recorded is not None else None

    def close(self) -> None:
        if self._items is not None:
            self._items.close()  # type: ignore[attr-defined]
            self._items = None
        self._pending.clear()

    @property
    def bytes_read(self) -> int:
        return self._scanner.bytes_read

    # ---- reading ----------------------------------------------------------------------------

    def _fill(self, horizon_ns: int, first_only: bool = False) -> None:
        """Read items until one message past ``horizon_ns`` (or the first message) is held."""
        items = self._items
        if items is None:
            return
        pending = self._pending
        start_ns = self._start_ns
        try:
            while self._read_ns <= horizon_ns:
                item = next(items)
                if type(item) is not RecordedMessage:
                    continue
                stamp = item.time_ns
                if start_ns is not None and stamp < start_ns:
                    continue
                self.messages_read += 1
                if self._first_ns is None:
                    self._first_ns = stamp
                if stamp < self._read_ns:
                    self._unsorted = True
                else:
                    self._read_ns = stamp
                pending.append((stamp, item))
                if first_only:
                    return
        except StopIteration:
            self._items = None
        except BagCorrupt as exc:
            self._items = None
            self.corruption = exc
            log.error("%s; the %d messages before it are replayed", exc, self.messages_read)
            at_ns = max(self._read_ns, self._first_ns or 0, start_ns or 0)
            pending.append((at_ns, BlackBoxEvent(
                at_ns / 1e9, "bag_corrupt",
                f"{exc}; the {self.messages_read:,} messages before it were replayed",
                str(self.path))))

    def _emit(self, stamp: int, msg: RecordedMessage, events: list[Event]) -> None:
        recorded = msg.topic
        name = recorded.name
        if name not in self._wanted:
            return
        if stamp < self._emitted_ns:
            self.out_of_order += 1
            stamp = self._emitted_ns
        self._emitted_ns = stamp
        t = stamp / 1e9
        publisher = recorded.publisher or placeholder_publisher(name)
        shown = self._shown.get(name)
        if shown is None or publisher not in shown:
            self._show(t, recorded, publisher, events)
        decoder = self._decoders.get(recorded)
        data = msg.data
        decode = (partial(_decode, decoder, data)
                  if decoder is not None and name in self._interest.decoded else None)
        events.append(MessageArrival(t, name, publisher, len(data), decode=decode,
                                     raw=partial(bytes, data)))

    def _show(self, t: float, recorded: RecordedTopic, publisher: str,
              events: list[Event]) -> None:
        """A new (topic, publisher): decoder, unknown-type report, graph snapshot."""
        name = recorded.name
        first = name not in self._shown
        self._shown.setdefault(name, []).append(publisher)
        self._topics.setdefault(name, recorded)
        if recorded not in self._decoders:
            try:
                self._decoders[recorded] = decoder_for(recorded)
            except UnknownBagType as exc:
                self._decoders[recorded] = None
                if first:
                    message = (f"{name}: cannot decode {recorded.type or 'its messages'}: "
                               f"{exc}; its arrivals (rate, size) are still observed, its "
                               "values are not")
                    log.warning("%s", message)
                    events.append(BlackBoxEvent(t, "bag_unknown_type", message, name))
        topics = {n: TopicInfo(n, self._topics[n].type, tuple(sorted(pubs)))
                  for n, pubs in self._shown.items()}
        events.append(GraphSnapshot(t, {}, topics))


def _stamp(entry: tuple[int, object]) -> int:
    return entry[0]


def _decode(decoder: Decoder, data: bytes | memoryview) -> object:
    try:
        return decoder(data)
    except Exception:
        return None


# ---- spec --------------------------------------------------------------------------------------

def open_bag(spec: str, options: SourceOptions) -> BagSource:
    """``bag:FILE`` or ``bag:FILE?rate=X&start=T`` (``start``: replay from T, epoch seconds).

    ``options.rate`` and ``options.start_time`` win over the query.
    """
    body = spec.removeprefix("bag:")
    if body.startswith("//"):
        body = body[2:]
    query: dict[str, str] = {}
    head, sep, tail = body.rpartition("?")
    if sep and "=" in tail and not Path(body).exists():
        body = head
        for part in tail.split("&"):
            key, eq, value = part.partition("=")
            if not eq or key not in ("rate", "start"):
                raise ConfigError(f"{spec}: unknown option {part!r} (allowed: rate, start)",
                                  "--source")
            query[key] = value
    if not body:
        raise ConfigError("bag: needs a file, e.g. bag:run.bag, bag:rosbag2_dir or "
                          "bag:run.mcap", "--source")
    try:
        rate = options.rate if options.rate is not None else float(query.get("rate", "1"))
        start = options.start_time
        if start is None and "start" in query:
            start = float(query["start"])
    except ValueError as exc:
        raise ConfigError(f"{spec}: bad option value: {exc}", "--source") from None
    if not rate > 0:
        raise ConfigError(f"{spec}: rate must be positive, got {rate}", "--source")
    path = Path(body)
    if not path.exists():
        raise ConfigError(f"{spec}: no such file or directory: {path}", "--source")
    return BagSource(path, realtime=options.realtime, rate=rate, start_time=start)


SOURCES.add("bag", SourceKind("bag", open_bag, BAG_CAPABILITIES, "bag:FILE"))
