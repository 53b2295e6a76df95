"""The black box on another computer over a thin link (thesis 6.2.2), in network namespaces.

The real thesis robot runs in one namespace, the black box in another, joined by a veth pair
shaped with ``tc tbf`` to about the thesis's Wi-Fi (8 Mbit/s; the camera alone sends 110).
Rates of topics a robot node subscribes to come from the publishers' counters, so the camera
at full rate raises no rate alarm, a real camera slowdown and a killed node are still seen;
with subscriptions only (``?counters=0``) the same link makes the camera look slow, and the
black box says it cannot keep up with it. About 75 s; skipped where namespaces cannot be
made, with the reason.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

import pytest

from blackbox.app import DEFAULT_CONFIG
from netns_link import (
    LinkUnavailable,
    ShapedLink,
    read_lines,
    robot_in,
    set_param,
    shaped_link,
    start_black_box,
    wait_for_file,
    why_not,
)

pytestmark = [pytest.mark.ros1, pytest.mark.slow]
_reason = why_not()
if _reason is not None:
    pytestmark.append(pytest.mark.skip(reason=_reason))

IMAGE = "/usb_cam/image_raw"


def _faulty(obs: list[dict[str, Any]], observer: str, *, topic: str | None = None,
            node: str | None = None, since: float, until: float) -> list[dict[str, Any]]:
    return [o for o in obs if o["observer"] == observer and o["faulty"]
            and since <= o["time"] <= until
            and (topic is None or o["resource"]["topic"] == topic)
            and (node is None or o["resource"]["node"] == node)]


@pytest.fixture
def link() -> Any:
    try:
        with shaped_link() as made:
            yield made
    except LinkUnavailable as exc:
        pytest.skip(f"cannot make the shaped link here: {exc}")


def test_counter_rates_keep_the_camera_right_over_a_thin_link(link: ShapedLink,
                                                             tmp_path: Path) -> None:
    with robot_in(link, tmp_path / "robot") as pids:
        out = tmp_path / "counters"
        out.mkdir()
        before = link.box_bytes()
        box = start_black_box(link, DEFAULT_CONFIG, out, duration=42)
        up = wait_for_file(out / "events.jsonl")
        time.sleep(max(0.0, up + 20 - time.time()))
        set_param(link, "/usb_cam/rate", 5.0)            # a real camera slowdown
        slowed = time.time()
        time.sleep(max(0.0, slowed + 10 - time.time()))
        set_param(link, "/usb_cam/rate", 15.0)
        time.sleep(max(0.0, up + 33 - time.time()))
        os.kill(pids["/audio_capture"], signal.SIGKILL)  # a node killed on the robot
        killed = time.time()
        assert box.wait(timeout=40) == 0
        after = link.box_bytes()
    obs = read_lines(out / "obs.jsonl")
    events = read_lines(out / "events.jsonl")
    start = next(e["time"] for e in events if e["kind"] == "start")

    assert any(e["kind"] == "ros1_rate_from_counters" and e["component"] == IMAGE
               for e in events)
    healthy = _faulty(obs, "hz", topic=IMAGE, since=start + 8, until=slowed)
    assert healthy == [], "camera at full rate must raise no rate alarm over the thin link"
    assert _faulty(obs, "hz", topic=IMAGE, since=slowed, until=slowed + 8)
    assert _faulty(obs, "activated", node="/audio_capture", since=killed, until=killed + 3)
    received = after[0] - before[0]
    # the camera alone is 110 Mbit/s; the black box took far less than the 8 Mbit/s link
    assert received < 0.5 * 8e6 / 8 * 42


def test_subscriptions_alone_make_the_camera_look_slow_and_say_so(link: ShapedLink,
                                                                 tmp_path: Path) -> None:
    with robot_in(link, tmp_path / "robot"):
        out = tmp_path / "subscribed"
        out.mkdir()
        box = start_black_box(link, DEFAULT_CONFIG, out, duration=20, counters=False)
        assert box.wait(timeout=60) == 0
    obs = read_lines(out / "obs.jsonl")
    events = read_lines(out / "events.jsonl")
    start = next(e["time"] for e in events if e["kind"] == "start")
    assert _faulty(obs, "hz", topic=IMAGE, since=start + 8, until=start + 20), \
        "the shaped link must be thinner than the camera stream for this test to mean anything"
    behind = [e for e in events if e["kind"] == "ros1_behind"]
    assert [e["component"] for e in behind] == [IMAGE]
    assert "cannot keep up" in behind[0]["message"]
