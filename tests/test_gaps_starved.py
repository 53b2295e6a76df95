"""CPU starvation read at the ROS 1 and ROS 2 sources' boundary (``schedstat`` files of our
own), replayed through the source's ``poll`` and the thesis's ``hz`` on ``/audio`` without a
robot: a
publisher the host starves of CPU is a measurement gap of its topics, not a wrong rate; the
black box starved is a gap of everything; a publisher that is stopped (waits for nothing)
still raises the alarm (docs/ros1.md and docs/ros2.md, "measurement gaps")."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest

from blackbox.events import Event, MeasurementGap, MessageArrival
from blackbox.model import BlackBoxEvent, Code, Observation
from blackbox.sources.cpu_wait import StarvationWatch
from blackbox.sources.ros1.source import Ros1Settings, Ros1Source
from blackbox.sources.ros2.source import Ros2Source
from isolation import fresh_domain
from test_gaps_ros1_switch import AUDIO, PERIOD, PUBLISHER, judge, thesis_hz

PID = 4242
HOLE = (2.05, 2.7)
"""Seconds after the start during which /audio's publisher sends nothing (0.65 s: one
period that long among the 50 of the thesis's window puts its mean over 0.04 s)."""


def write_wait(root: Path, pid: int | str, seconds: float) -> None:
    path = root / str(pid) / "task" / str(pid) / "schedstat"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"1000 {round(seconds * 1e9)} 3\n", encoding="ascii")


Source = Ros1Source | Ros2Source


def ros1() -> tuple[Source, Callable[[list[MessageArrival]], None]]:
    source = Ros1Source("http://127.0.0.1:9/", Ros1Settings())  # never started: no robot
    return source, source._push_batch


def ros2() -> tuple[Source, Callable[[list[MessageArrival]], None]]:
    source = Ros2Source(fresh_domain())  # never started: no DDS participant

    def push(arrivals: list[MessageArrival]) -> None:
        for a in arrivals:
            source._push(a)
    return source, push


@pytest.fixture(params=[ros1, ros2], ids=["ros1", "ros2"])
def make(request: pytest.FixtureRequest) -> Callable[[], tuple[
        Source, Callable[[list[MessageArrival]], None]]]:
    return request.param  # type: ignore[no-any-return]


def replay(root: Path, waits: dict[float, tuple[float, float]],
           make: Callable[[], tuple[Source, Callable[[list[MessageArrival]], None]]]
           ) -> tuple[list[Observation], list[Event]]:
    """/audio at 33 Hz with a hole of ``HOLE``, handed out by ``poll`` every 0.5 s for 4 s.
    ``waits``: horizon (seconds after the start) -> (the publisher's, the black box's)
    cumulative run-queue wait written just before that poll."""
    source, push = make()
    source.starvation.watch = StarvationWatch(root)
    source.starvation.local_publishers = ({PUBLISHER: PID}, {PUBLISHER: (AUDIO,)})
    write_wait(root, PID, 0.0)
    write_wait(root, "self", 0.0)
    hz = thesis_hz(AUDIO)
    start = time.time()
    stamps = [start + PERIOD * k for k in range(int(4.0 / PERIOD))]
    push([MessageArrival(t, AUDIO, PUBLISHER, 480) for t in stamps
          if not HOLE[0] < t - start < HOLE[1]])
    verdicts: list[Observation] = []
    handed: list[Event] = []
    for k in range(1, 9):
        if k * 0.5 in waits:
            node, own = waits[k * 0.5]
            write_wait(root, PID, node)
            write_wait(root, "self", own)
        events = source.poll(start + 0.5 * k)
        handed.extend(events)
        verdicts.append(judge(hz, events, start + 0.5 * k))
    return verdicts, handed


def faulty(verdicts: list[Observation]) -> list[str]:
    return [v.message for v in verdicts if v.code not in (Code.GENERAL_OK, Code.NOT_AVAILABLE)]


def test_a_publisher_the_host_starves_is_a_gap_of_its_topics_not_a_wrong_rate(
        tmp_path: Path, make: Callable[[], tuple[Source, Callable[[list[MessageArrival]], None]]]
) -> None:
    """The publisher waited 0.4 s and then 0.25 s more on the run queue while its messages
    stopped (runnable, no core): its topics are unmeasured over those polls, the host is
    reported saturated, and ``hz`` keeps judging /audio healthy around it. Before, the
    0.65 s period reached ``hz``: 0.042 s against 0.03 +- 0.01, a false alarm."""
    verdicts, handed = replay(tmp_path, {2.5: (0.4, 0.0), 3.0: (0.65, 0.0)}, make)
    assert faulty(verdicts) == []
    gaps = [e for e in handed if isinstance(e, MeasurementGap)]
    assert gaps and all(g.topic == AUDIO and "host starved" in g.reason for g in gaps)
    assert all(g.timing_only for g in gaps), "a starved publisher's values are its own"
    covered = [(g.start, g.end) for g in gaps]
    late = verdicts[0].time - 0.5 + HOLE[1]  # the first message after the hole
    assert any(s < late <= (e or 0) for s, e in covered), \
        f"the late message at {late} is outside the gaps {covered}"
    saturated = [e for e in handed if isinstance(e, BlackBoxEvent)
                 and e.kind.endswith("_host_saturated")]
    assert len(saturated) == 1 and PUBLISHER in saturated[0].message
    assert verdicts[-1].code == Code.GENERAL_OK, "never judged again after the starvation"


def test_a_stopped_publisher_waits_for_nothing_and_its_silence_is_still_judged(
        tmp_path: Path, make: Callable[[], tuple[Source, Callable[[list[MessageArrival]], None]]]
) -> None:
    """The same hole with no run-queue wait (a SIGSTOP, a hung node): no gap, and ``hz``
    reports the long period: the black box is not blinded by the starvation rule."""
    verdicts, handed = replay(tmp_path, {}, make)
    assert not [e for e in handed if isinstance(e, MeasurementGap)]
    assert faulty(verdicts), "the 0.65 s hole raised no alarm"


def test_the_black_box_starved_is_a_gap_of_everything(
        tmp_path: Path, make: Callable[[], tuple[Source, Callable[[list[MessageArrival]], None]]]
) -> None:
    """A thread of the black box waited 1.6 s on the run queue within 2 s: what it stamped
    in that stretch is its own lateness, a gap of everything and no verdict."""
    verdicts, handed = replay(tmp_path, {2.5: (0.0, 0.8), 3.0: (0.0, 1.6)}, make)
    gaps = [e for e in handed if isinstance(e, MeasurementGap)]
    assert gaps and all(g.everything and "a thread of the black box waited" in g.reason
                        and g.timing_only for g in gaps)
    assert faulty(verdicts) == []
