"""Learning reads a message's header stamp once: the one read times the message's samples
for relations and is the stamp's own ``age`` sample (review item 2)."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from blackbox.events import Interest, MessageArrival
from blackbox.learn.recording import Recorder, Recording, TopicRecord


@dataclass(frozen=True)
class Stamp:
    sec: int
    nanosec: int


class CountedHeader(Mapping[str, Stamp]):
    """A header (a mapping, as some decoders give) that counts how often its stamp is
    read."""

    reads = 0

    def __init__(self, t: float) -> None:
        sec = math.floor(t)
        self._stamp = Stamp(sec, round((t - sec) * 1e9))

    def __getitem__(self, key: str) -> Stamp:
        if key != "stamp":
            raise KeyError(key)
        CountedHeader.reads += 1
        return self._stamp

    def __iter__(self) -> Iterator[str]:
        return iter(("stamp",))

    def __len__(self) -> int:
        return 1


@dataclass(frozen=True)
class Imu:
    header: CountedHeader
    z: float


def recorder() -> tuple[Recorder, TopicRecord]:
    recording = Recording("test", 0.0)
    topic = recording.topics["/imu"] = TopicRecord("/imu", "sensor_msgs/msg/Imu",
                                                   {"/imu_driver"})
    return Recorder(recording, Interest(topics=frozenset({"/imu"}),
                                        decoded=frozenset({"/imu"}))), topic


def arrival(stamped: float, delay: float, z: float) -> MessageArrival:
    return MessageArrival(stamped + delay, "/imu", "/imu_driver", 8,
                          value=Imu(CountedHeader(stamped), z))


def test_each_message_after_the_first_reads_its_stamp_once() -> None:
    rec, topic = recorder()
    rec.on_message(arrival(10.0, 0.01, 0.5))  # the first also discovers the fields
    before = CountedHeader.reads
    for k in range(1, 51):
        rec.on_message(arrival(10.0 + k * 0.05, 0.01, 0.5))
    assert CountedHeader.reads - before == 50
    assert topic.stamp_path == "header.stamp"


def stamp_of(t: float) -> float:
    """The seconds a ``CountedHeader(t)`` carries (whole nanoseconds)."""
    sec = math.floor(t)
    return float(sec) + float(round((t - sec) * 1e9)) * 1e-9


def test_the_one_read_times_the_samples_and_gives_the_age() -> None:
    rec, topic = recorder()
    stamps = [10.0 + k * 0.05 for k in range(20)]
    for k, t in enumerate(stamps):
        rec.on_message(arrival(t, 0.02, float(k)))
    (stamp,) = [f for f in topic.fields if f.info.kind == "stamp"]
    assert stamp.series["age"].values == [t + 0.02 - stamp_of(t) for t in stamps]
    assert stamp.problems == 0
    (z,) = [f for f in topic.fields if f.info.path == "z"]
    assert list(z.timed["value"].times) == [stamp_of(t) for t in stamps]


def test_an_unreadable_stamp_is_counted_once_and_the_arrival_times_the_sample() -> None:
    rec, topic = recorder()
    rec.on_message(arrival(10.0, 0.02, 1.0))
    rec.on_message(MessageArrival(10.07, "/imu", "/imu_driver", 8,
                                  value={"header": {"stamp": "noon"}, "z": 2.0}))
    (stamp,) = [f for f in topic.fields if f.info.kind == "stamp"]
    assert stamp.problems == 1 and "not a time" in stamp.last_problem
    (z,) = [f for f in topic.fields if f.info.path == "z"]
    assert z.timed["value"].times[-1] == 10.07
