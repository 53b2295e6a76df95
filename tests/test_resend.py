"""A command that got no answer is written again, and the robot tells a resend crossing its
answer (ignored) from one whose answer was lost (answered again, an IBIT with the result it
already has). Pure: time is passed in."""

from __future__ import annotations

from blackbox.transport.resend import REMEMBERED, REPEAT_AFTER, RESEND_MAX, RecentAnswers, Resend


def test_a_resend_waits_one_second_then_twice_as_long_up_to_the_cap() -> None:
    resend = Resend(sent=100.0)
    due = [t / 10 for t in range(1000, 1400) if resend.due(t / 10)]
    assert due == [101.0, 103.0, 107.0, 111.0, 115.0, 119.0, 123.0, 127.0, 131.0, 135.0, 139.0]
    assert resend.wait == RESEND_MAX


def test_a_repeat_right_after_the_answer_is_a_crossing_a_later_one_is_a_lost_answer() -> None:
    recent: RecentAnswers[int, str] = RecentAnswers()
    assert not recent.crossing(7, 10.0) and recent.get(7) is None
    recent.answered(7, 10.0, "result")
    assert recent.crossing(7, 10.0 + REPEAT_AFTER / 2)
    assert not recent.crossing(7, 10.0 + REPEAT_AFTER)
    assert recent.get(7) == "result"


def test_only_the_most_recent_answers_are_remembered() -> None:
    recent: RecentAnswers[int, int] = RecentAnswers()
    for key in range(REMEMBERED + 5):
        recent.answered(key, float(key), key)
    assert recent.get(0) is None and recent.get(4) is None
    assert recent.get(5) == 5 and len(recent.entries) == REMEMBERED
    recent.answered(5, 100.0, 50)  # answered again: newest, kept longest
    for key in range(200, 200 + REMEMBERED - 1):
        recent.answered(key, 101.0, key)
    assert recent.get(5) == 50
