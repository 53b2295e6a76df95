"""A relation observer says how many messages of its topics did not decode (review item 3):
they give it no samples, so a relation goes stale without them, and the operator reads why
in the observation (its message and ``values["undecodable"]``), as other observers report
the messages they skip. Counted per evaluation, like theirs."""

from __future__ import annotations

import math
import textwrap

from blackbox.events import MessageArrival
from blackbox.model import Observation
from blackbox.observe.build import build_observer, load_config_text
from blackbox.observe.observers import relation
from blackbox.observe.observers.relation import RelationObserver


def documented_example() -> str:
    """The observer entry of the module's own documentation (its ``code-block:: yaml``)."""
    doc = relation.__doc__ or ""
    block = doc.split(".. code-block:: yaml", 1)[1].split('"""', 1)[0]
    return "version: 1\nobservers:\n" + textwrap.indent(textwrap.dedent(block).strip(), "  ")


def observer() -> RelationObserver:
    (entry,) = load_config_text(documented_example(), "robot.yaml").observers
    obs = build_observer(entry)
    assert isinstance(obs, RelationObserver)
    return obs


def garbage() -> object:
    raise ValueError("truncated CDR")


def drive(obs: RelationObserver, start: float, end: float, *, imu_decodes: bool = True,
          undecodable_every: int = 0) -> list[Observation]:
    """Messages at 20 Hz over ``[start, end)`` of a turning command and an IMU that agrees
    with it, evaluated at each whole second after ``start`` up to ``end``; every
    ``undecodable_every``-th IMU message (or each one) does not decode: half of those fail
    in the decoder, half come from a source that cannot decode the topic."""
    out: list[Observation] = []
    for k in range(round(start * 20), round(end * 20) + 1):
        t = k / 20
        if k % 20 == 0 and t > start:
            out.extend(obs.evaluate(t))
        if t >= end:
            break
        w = 0.5 * math.sin(2 * math.pi * t / 7.0)
        obs.on_message(MessageArrival(t, "/cmd_yaw", "/teleop", 8, value={"data": w}))
        broken = not imu_decodes or (undecodable_every and k % undecodable_every == 0)
        if not broken:
            obs.on_message(MessageArrival(t + 0.01, "/imu/data", "/imu", 8,
                                          value={"angular_velocity": {"z": w}}))
        elif k % 2:
            obs.on_message(MessageArrival(t + 0.01, "/imu/data", "/imu", 8, decode=garbage))
        else:
            obs.on_message(MessageArrival(t + 0.01, "/imu/data", "/imu", 8))
    return out


def test_messages_that_do_not_decode_are_counted_in_the_next_observation() -> None:
    obs = observer()
    drive(obs, 0.0, 20.0)
    (seen,) = drive(obs, 20.0, 21.0, undecodable_every=5)
    assert seen.values["undecodable"] == 4.0, seen
    assert "4 messages of /imu/data did not decode since the last evaluation" in seen.message


def test_the_count_starts_afresh_after_each_evaluation() -> None:
    obs = observer()
    drive(obs, 0.0, 20.0)
    reported = drive(obs, 20.0, 23.0, undecodable_every=5)
    assert [o.values.get("undecodable") for o in reported] == [4.0, 4.0, 4.0]
    (clean,) = drive(obs, 23.0, 24.0)
    assert "undecodable" not in clean.values
    assert "did not decode" not in clean.message


def test_a_topic_that_never_decodes_is_named_beside_the_stale_relation() -> None:
    obs = observer()
    drive(obs, 0.0, 20.0)
    observations = drive(obs, 20.0, 25.0, imu_decodes=False)
    last = observations[-1]
    assert last.values["undecodable"] == 20.0
    assert "stale" in last.message and "20 messages of /imu/data did not decode" in \
        last.message, last.message


def test_a_healthy_relation_reports_no_undecodable_messages() -> None:
    obs = observer()
    observations = drive(obs, 0.0, 30.0)
    assert all("undecodable" not in o.values for o in observations)
