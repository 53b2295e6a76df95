"""Logging policies: changes always, periodic, state-driven and event-driven sampling."""

from __future__ import annotations

from blackbox.model import Code, Observation, Resource, State
from blackbox.record.policy import FaultBoost, LoggingPolicy, PolicyRule, PolicyTracker

OK = (State(1, "ok"),)
DEGRADED = (State(2, "degraded"),)
CAM = Resource(topic="/usb_cam/image_raw")


def run(policy: LoggingPolicy, codes: dict[int, tuple[Code, tuple[State, ...]]],
        seconds: int, observer: str = "hz", resource: Resource = CAM) -> list[tuple[int, str]]:
    """Feed one observation a second; ``codes`` switches code/states from a second on."""
    tracker = PolicyTracker(policy)
    code, states = Code.GENERAL_OK, OK
    logged = []
    for t in range(seconds):
        code, states = codes.get(t, (code, states))
        d = tracker.decide(Observation(float(t), observer, resource, code, states))
        if d is not None:
            logged.append((t, d.kind))
    return logged


def test_healthy_characteristic_is_logged_once_then_every_interval() -> None:
    policy = LoggingPolicy(default=PolicyRule(interval=10.0))
    assert run(policy, {}, 31) == [(0, "observation"), (10, "sample"), (20, "sample"),
                                   (30, "sample")]


def test_no_interval_logs_only_changes() -> None:
    policy = LoggingPolicy(default=PolicyRule(interval=None, on_fault=None))
    codes = {5: (Code.NO_STATE_FITS, ()), 8: (Code.GENERAL_OK, OK)}
    assert run(policy, codes, 100) == [(0, "observation"), (5, "exceedance"), (8, "observation")]


def test_fault_logs_faster_for_a_while_and_asks_for_a_snapshot() -> None:
    policy = LoggingPolicy(default=PolicyRule(interval=60.0,
                                              on_fault=FaultBoost(interval=2.0, duration=6.0)))
    tracker = PolicyTracker(policy)
    decisions = {}
    for t in range(40):
        code, states = (Code.NO_STATE_FITS, ()) if 10 <= t < 30 else (Code.GENERAL_OK, OK)
        d = tracker.decide(Observation(float(t), "hz", CAM, code, states))
        if d is not None:
            decisions[t] = (d.kind, d.fault_started, d.snapshot)
    # Fault at 10: samples every 2 s until 16 (exclusive), then the 60 s interval again.
    assert decisions == {
        0: ("observation", False, False),
        10: ("exceedance", True, True),
        12: ("sample", False, False),
        14: ("sample", False, False),
        30: ("observation", False, False),
    }


def test_state_driven_interval_applies_while_the_state_fits() -> None:
    policy = LoggingPolicy(default=PolicyRule(interval=60.0, on_fault=None,
                                              states={"degraded": 3.0}))
    codes = {5: (Code.GENERAL_OK, DEGRADED), 12: (Code.GENERAL_OK, OK)}
    assert run(policy, codes, 30) == [(0, "observation"), (5, "observation"), (8, "sample"),
                                      (11, "sample"), (12, "observation")]


def test_state_may_be_named_by_number() -> None:
    policy = LoggingPolicy(default=PolicyRule(interval=None, on_fault=None, states={"2": 4.0}))
    codes = {1: (Code.GENERAL_OK, DEGRADED)}
    assert run(policy, codes, 10) == [(0, "observation"), (1, "observation"), (5, "sample"),
                                      (9, "sample")]


def test_first_matching_rule_wins_by_entity_and_characteristic() -> None:
    policy = LoggingPolicy(
        rules=(PolicyRule(entity="/usb_cam/*", characteristic="hz", interval=5.0),
               PolicyRule(entity="/usb_cam/*", interval=7.0)),
        default=PolicyRule(interval=60.0))
    assert policy.rule_for("/usb_cam/image_raw", "hz").interval == 5.0
    assert policy.rule_for("/usb_cam/image_raw", "timeout").interval == 7.0
    assert policy.rule_for("/audio", "hz").interval == 60.0
    assert run(policy, {}, 16) == [(0, "observation"), (5, "sample"), (10, "sample"),
                                   (15, "sample")]


def test_channels_are_told_apart_by_observer_and_full_resource() -> None:
    tracker = PolicyTracker(LoggingPolicy())
    a = tracker.decide(Observation(0.0, "hz", Resource(topic="/t", publishers=("/a",)),
                                   Code.GENERAL_OK, OK))
    b = tracker.decide(Observation(0.0, "hz", Resource(topic="/t", publishers=("/b",)),
                                   Code.GENERAL_OK, OK))
    node = tracker.decide(Observation(0.0, "activated", Resource(node="/n"), Code.GENERAL_OK))
    assert a is not None and b is not None and node is not None
    assert a.channel[:2] == b.channel[:2] == ("/t", "hz")
    assert a.channel != b.channel
    assert node.channel[:2] == ("/n", "activated")
