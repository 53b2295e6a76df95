"""The operator's headline: one line in plain words (what, since when, how sure, what to do),
the evidence as a structured list; and one status rule for a robot everywhere."""

from __future__ import annotations

from typing import Any

import pytest

from blackbox.station.headline import (
    diagnosis_headlines,
    duration_words,
    event_headline,
    since_words,
)
from blackbox.station.status import robot_status

T = 1_790_000_000.0  # 2026-09-21 ~14:13 UTC
CAUSE = ("2 of 14 observations failed: alive on /usb_cam (NOT_AVAILABLE); rate on "
         "/usb_cam/image_raw (TIMEOUT). The observations do not tell node /usb_cam apart "
         "from 1 other explanation of the same size (topic /usb_cam/image_raw); node "
         "/usb_cam ranks first by prior fault probability.")
FAILURE: dict[str, Any] = {
    "proprietary_fault_code": "NOT_AVAILABLE,TIMEOUT",
    "operator_action": "Stop the mission and drive home on lidar",
    "maintenance_action": "Replace the camera cable",
    "consequence": "No images for the operator",
    "complementary": "candidates: {/usb_cam} | {/usb_cam/image_raw}; engine hybrid (agree)",
}


def test_a_failure_reads_as_one_line_with_certainty_and_the_operators_action() -> None:
    h = event_headline("failure", "/usb_cam",
                       "/usb_cam diagnosed faulty (best of 2 candidate explanations): " + CAUSE,
                       FAILURE, T)
    assert h.text == "/usb_cam is not running"
    assert (h.severity, h.since, h.certainty) == ("bad", T, "one of 2 explanations")
    assert h.operator_action == "Stop the mission and drive home on lidar"
    assert h.maintenance_action == "Replace the camera cable"
    evidence = {e.label: e.items for e in h.evidence}
    assert evidence["Failed observations"] == ("alive on /usb_cam (NOT_AVAILABLE)",
                                               "rate on /usb_cam/image_raw (TIMEOUT)")
    assert evidence["Held observations"] == ("12 of 14 held",)
    assert evidence["Alternative explanations"] == ("{/usb_cam/image_raw}",)
    assert evidence["Diagnosed by"] == ("hybrid (agree)",)
    assert evidence["Consequence"] == ("No images for the operator",)


def test_a_unique_explanation_says_so_and_unknown_codes_read_not_working() -> None:
    h = event_headline("failure", "/imu", "/imu diagnosed faulty: yaw rate disagrees",
                       {"proprietary_fault_code": "GENERAL_ERROR",
                        "complementary": "candidates: {/imu}; engine cbd"}, T)
    assert (h.text, h.certainty) == ("/imu is not working", "unique")
    assert {e.label: e.items for e in h.evidence}["Failed observations"] == (
        "yaw rate disagrees",)
    assert h.operator_action == ""  # the model knows none: nothing invented


def test_a_logged_failure_without_ucms_fields_still_gets_a_plain_headline() -> None:
    h = event_headline("failure", "/usb_cam", "/usb_cam diagnosed faulty", {"log_id": 3}, T)
    assert (h.text, h.certainty, h.evidence) == ("/usb_cam is not working", "", ())


@pytest.mark.parametrize(("kind", "details", "text", "severity"), [
    ("rectification", {}, "/usb_cam works again", "good"),
    ("diagnosis", {"components": ["/a", "/b"]}, "/a, /b are diagnosed faulty", "bad"),
    ("diagnosis", {"components": []}, "No failure diagnosed any more", "good"),
])
def test_other_events_have_headlines_of_their_own(kind: str, details: dict[str, Any],
                                                   text: str, severity: str) -> None:
    h = event_headline(kind, "/usb_cam", "long prose", details, T)
    assert (h.text, h.severity) == (text, severity)


def test_since_when_is_a_clock_time_and_how_long() -> None:
    assert since_words(T, T + 12) == "since 14:13:20 UTC, 12 s"
    assert since_words(T, T + 2 * 86400).startswith("since 2026-09-21 14:13:20 UTC, 2 d")
    assert since_words(None, T) == ""
    assert [duration_words(s) for s in (0, 59, 61, 3700, 90000)] == [
        "0 s", "59 s", "1 min 01 s", "1 h 01 min", "1 d 1 h"]


def test_the_robot_page_says_what_is_wrong_first_and_all_is_well_when_it_is() -> None:
    failures = {"/usb_cam": ("/usb_cam diagnosed faulty: " + CAUSE, FAILURE, T)}
    [line] = diagnosis_headlines("thesis", ["/usb_cam"], T, failures)
    assert (line.text, line.since) == ("/usb_cam is not running", T)
    [fine] = diagnosis_headlines("thesis", [], None, {})
    assert (fine.text, fine.severity) == ("Everything is working: no failure diagnosed", "good")
    [warn] = diagnosis_headlines("thesis", [], None, {}, ["/imu"])
    assert warn.text == "No failure diagnosed; /imu shows threshold exceedances"
    silent, failed = diagnosis_headlines("thesis", ["/usb_cam"], T, {}, stale=True)
    assert silent.text == "thesis is silent: what is shown may be out of date"
    assert (failed.text, failed.since) == ("/usb_cam is not working", T)


@pytest.mark.parametrize(("statuses", "shown"), [
    (["OPERATIONAL", "OPERATIONAL"], "OPERATIONAL"),
    (["DEGRADED", "NOT_OPERATIONAL", "OPERATIONAL"], "DEGRADED"),  # the robot still drives
    (["NOT_OPERATIONAL", "NOT_OPERATIONAL", "UNKNOWN"], "NOT_OPERATIONAL"),
    (["UNKNOWN"], "UNKNOWN"),
    ([], "UNKNOWN"),
])
def test_a_robots_status_follows_the_ucms_rule_over_its_entities(statuses: list[str],
                                                                  shown: str) -> None:
    assert robot_status(statuses, stale=False, online=True) == shown


def test_a_silent_or_stopped_robot_is_unknown_whatever_it_last_said() -> None:
    assert robot_status(["OPERATIONAL"], stale=True, online=True) == "UNKNOWN"
    assert robot_status(["NOT_OPERATIONAL"], stale=False, online=False) == "UNKNOWN"
