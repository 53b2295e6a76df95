"""Scoring detections against ground truth: hand-built faults and observation sequences with
hand-computed confusion counts, the thesis's measures and its published numbers."""

from __future__ import annotations

import math

import pytest

from blackbox.evaluate import (
    THESIS_AFTER,
    THESIS_BEFORE,
    Confusion,
    by_kind,
    episodes,
    fault_components,
    isolation_by_kind,
    percentile,
    resource_components,
    score_run,
)
from blackbox.model import Code, Diagnosis, Observation, Resource
from blackbox.sources.sim import GroundTruth

PUBLISHERS = {"/cam/image": "/cam", "/sig": "/gen"}
CAM_NODE = Resource(node="/cam")
SIG = Resource(topic="/sig")


def series(observer: str, resource: Resource, pattern: str, start: float = 0.0,
           faulty: Code = Code.NO_STATE_FITS) -> list[Observation]:
    """One observation per second: ``.`` OK, ``x`` faulty."""
    return [Observation(start + i, observer, resource, faulty if c == "x" else Code.GENERAL_OK)
            for i, c in enumerate(pattern)]


KILL_CAM = GroundTruth(2.0, 4.0, "kill", "/cam", "/cam")
OFFSET_SIG = GroundTruth(6.0, 7.0, "offset", "/sig", "/gen", {"value": 3.0})


def small_run(**kwargs: object):
    # t:          0123456789
    active = series("activated", CAM_NODE, "...xxx..x.")
    scores = series("scores", SIG, "x.........")
    return score_run([KILL_CAM, OFFSET_SIG], active + scores, PUBLISHERS, start=0.0, end=10.0,
                     grace=1.0, **kwargs)  # type: ignore[arg-type]


def test_hand_built_run_gives_hand_computed_confusion_counts() -> None:
    """Windows (grace 1 s): kill /cam [2, 5], offset /sig [6, 8].

    activated /cam episodes: [3, 5] starts inside the kill's window -> TP (delay 1 s);
    [8, 8] overlaps no window of a /cam fault -> FP. scores /sig: episode [0, 0] -> FP; OK
    during the offset's window -> the offset is a FN. TN: activated OK at 0, 1, 6, 7, 9 (2 is
    inside the kill's window) and scores OK at 1-5 and 9 (6-8 inside the offset's window).
    """
    score = small_run()
    assert score.confusion == Confusion(tp=1, fp=2, fn=1, tn=11)
    kill, offset = score.outcomes
    assert kill.detected and kill.delay == pytest.approx(1.0)
    assert kill.detected_by == ("activated", CAM_NODE)
    assert not offset.detected and offset.delay is None
    assert [(e.key[0], e.start, e.end) for e in score.false_positives] == [
        ("scores", 0.0, 0.0), ("activated", 8.0, 8.0)]


def test_measures_follow_thesis_equations_6_1_to_6_4() -> None:
    c = small_run().confusion
    assert c.accuracy == pytest.approx(12 / 15)        # (TP + TN) / all
    assert c.accuracy_without_tn == pytest.approx(1 / 4)
    assert c.precision == pytest.approx(1 / 3)
    assert c.recall == pytest.approx(1 / 2)
    assert c.f1 == pytest.approx(0.4)                  # 2 * (1/6) / (5/6)


def test_thesis_accuracies_are_tp_over_tp_fp_fn_that_is_tn_zero() -> None:
    """Table 6.7: 240 TP, 60 FP, 35 FN printed as 71.64 %, precision 0.8, recall 0.88 (the
    counts give 0.873), F1 0.83. Table 6.8: 276/23/12 printed as 88 %, 0.92, 0.96, 0.93 (the
    counts give F1 0.940)."""
    before, after = THESIS_BEFORE.confusion, THESIS_AFTER.confusion
    assert before.accuracy == pytest.approx(0.7164, abs=5e-5)
    assert before.accuracy == before.accuracy_without_tn
    assert before.precision == pytest.approx(0.80)
    assert before.recall == pytest.approx(240 / 275)
    assert round(before.f1, 2) == THESIS_BEFORE.f1
    assert after.accuracy == pytest.approx(276 / 311)
    assert round(after.accuracy, 2) == 0.89 and int(100 * after.accuracy) == 88
    assert round(after.precision, 2) == THESIS_AFTER.precision
    assert round(after.recall, 2) == THESIS_AFTER.recall
    assert after.f1 == pytest.approx(552 / 587)         # 2TP / (2TP + FP + FN)


def test_undefined_measures_are_none_not_zero() -> None:
    quiet = Confusion(tn=100)
    assert quiet.precision is None and quiet.recall is None and quiet.f1 is None
    assert quiet.accuracy == 1.0
    assert Confusion().accuracy is None
    assert Confusion(fp=1, fn=1).f1 is None           # precision = recall = 0
    assert Confusion(1, 2, 3, 4) + Confusion(10, 20, 30, 40) == Confusion(11, 22, 33, 44)


def test_a_fault_belongs_to_its_node_and_topics_or_its_topic_and_publisher() -> None:
    assert fault_components(KILL_CAM, PUBLISHERS) == {"/cam", "/cam/image"}
    hog = GroundTruth(0.0, 1.0, "cpu_hog", "/gen", "/gen", {"percent": 90.0})
    assert fault_components(hog, PUBLISHERS) == {"/gen", "/sig"}
    stall = GroundTruth(0.0, 1.0, "stall", "/cam/image", "/cam")
    assert fault_components(stall, PUBLISHERS) == {"/cam/image", "/cam"}
    assert resource_components(Resource(topic="/a", topic_b="/b", publishers=("/p",))) == {
        "/a", "/b", "/p"}
    assert resource_components(Resource(interface="eth0")) == frozenset()


def test_a_topic_fault_is_detected_on_its_publisher_node() -> None:
    stall = GroundTruth(10.0, 15.0, "stall", "/cam/image", "/cam")
    score = score_run([stall], series("activated", CAM_NODE, "..x", start=10.0), PUBLISHERS,
                      start=0.0, end=20.0)
    assert score.confusion.tp == 1 and score.outcomes[0].delay == pytest.approx(2.0)


def test_an_unrelated_resource_neither_detects_nor_is_excused() -> None:
    """A failed observation of /sig during a camera fault is a false alarm, and the camera
    fault stays undetected."""
    stall = GroundTruth(10.0, 15.0, "stall", "/cam/image", "/cam")
    score = score_run([stall], series("timeout", SIG, "xxx..", start=10.0), PUBLISHERS,
                      start=0.0, end=20.0)
    assert score.confusion == Confusion(tp=0, fp=1, fn=1, tn=2)


def test_an_episode_already_running_at_the_fault_start_does_not_detect_it() -> None:
    """It started before the window, so it is no evidence of this fault; it overlaps the
    window, so it is no false alarm either."""
    offset = GroundTruth(5.0, 8.0, "offset", "/sig", "/gen", {"value": 3.0})
    score = score_run([offset], series("scores", SIG, "xxxxxxxx.."), PUBLISHERS, start=0.0,
                      end=10.0, grace=0.0)
    assert score.confusion == Confusion(tp=0, fp=0, fn=1, tn=1)


def test_grace_is_a_closed_interval_after_the_end() -> None:
    rate = GroundTruth(1.0, 3.0, "rate", "/sig", "/gen", {"factor": 0.5})
    late = series("hz", SIG, "x", start=5.0)
    assert score_run([rate], late, PUBLISHERS, start=0.0, end=10.0, grace=2.0).confusion.tp == 1
    assert score_run([rate], late, PUBLISHERS, start=0.0, end=10.0, grace=1.9).confusion == (
        Confusion(tp=0, fp=1, fn=1))


def test_a_fault_still_active_at_the_end_runs_to_the_end_of_the_run() -> None:
    open_ended = GroundTruth(5.0, None, "kill", "/cam", "/cam")
    score = score_run([open_ended], series("activated", CAM_NODE, "....xx....x"), PUBLISHERS,
                      start=0.0, end=10.0, grace=0.0)
    assert score.outcomes[0].end == 10.0
    # t=4 starts before the fault (5): that episode [4, 5] overlaps, no FP, no TP; t=10 starts
    # inside [5, 10]: TP with a delay of 5 s.
    assert score.confusion == Confusion(tp=1, fp=0, fn=0, tn=4)
    assert score.outcomes[0].delay == pytest.approx(5.0)


def test_not_available_counts_as_faulty_like_every_negative_code() -> None:
    obs = series("resources", CAM_NODE, ".xx.", faulty=Code.NOT_AVAILABLE)
    assert [(e.start, e.end, e.count) for e in episodes(obs)] == [(1.0, 2.0, 2)]


def test_episodes_are_per_observer_key_and_interleave() -> None:
    a = series("hz", SIG, "xx.x")
    b = series("timeout", SIG, ".xxx")
    found = episodes(b + a)
    assert [(e.key[0], e.start, e.end) for e in found] == [
        ("hz", 0.0, 1.0), ("timeout", 1.0, 3.0), ("hz", 3.0, 3.0)]


def test_diagnoses_score_isolation_and_wrong_first_candidates() -> None:
    """Kill window [2, 5], offset window [6, 8]: the diagnosis at 3 names /cam first
    (isolates the kill after 1 s), at 8 names /gen (isolates the offset although no
    observation saw it), at 9 names /cam outside every window (wrong); an empty diagnosis
    is not a claim."""
    diagnoses = [
        Diagnosis(3.0, (frozenset({"/cam"}), frozenset({"/cam/image"}))),
        Diagnosis(4.0, (frozenset({"/cam/image"}),)),
        Diagnosis(6.0, ()),
        Diagnosis(8.0, (frozenset({"/gen", "/cam"}),)),
        Diagnosis(9.0, (frozenset({"/cam"}),)),
    ]
    score = small_run(diagnoses=diagnoses)
    assert score.diagnosis is not None
    assert (score.diagnosis.isolated, score.diagnosis.correct, score.diagnosis.wrong) == (2, 3, 1)
    kill, offset = score.outcomes
    assert kill.isolation_delay == pytest.approx(1.0)
    assert offset.isolated and offset.isolation_delay == pytest.approx(2.0)
    assert small_run().diagnosis is None and small_run().outcomes[0].isolated is None


def test_a_fault_listed_after_the_first_candidate_is_in_the_candidates_not_top_1() -> None:
    """Kill window [2, 5], offset window [6, 8]: the diagnoses name the generator only in
    second place, and never /cam; a diagnosis after the window does not count."""
    diagnoses = [
        Diagnosis(3.0, (frozenset({"/cam/image"}),)),
        Diagnosis(7.0, (frozenset({"/other"}), frozenset({"/gen"}))),
        Diagnosis(9.5, (frozenset({"/other"}), frozenset({"/cam"}))),
    ]
    score = small_run(diagnoses=diagnoses)
    assert score.diagnosis is not None
    assert (score.diagnosis.isolated, score.diagnosis.in_candidates) == (1, 2)
    assert score.diagnosis.candidate_rate == 1.0 and score.diagnosis.isolation_rate == 0.5
    kill, offset = score.outcomes
    assert (kill.isolated, kill.in_candidates) == (True, True)  # its topic is one of its parts
    assert (offset.isolated, offset.in_candidates) == (False, True)
    assert [k.to_dict() for k in isolation_by_kind(score.outcomes)] == [
        {"kind": "kill", "faults": 1, "isolated": 1, "isolation_rate": 1.0, "in_candidates": 1,
         "candidate_rate": 1.0},
        {"kind": "offset", "faults": 1, "isolated": 0, "isolation_rate": 0.0,
         "in_candidates": 1, "candidate_rate": 1.0}]
    assert isolation_by_kind(small_run().outcomes) == []


def test_per_kind_summary_and_nearest_rank_percentiles() -> None:
    kinds = by_kind(small_run().outcomes)
    assert [(k.kind, k.faults, k.detected, k.delays) for k in kinds] == [
        ("kill", 1, 1, (1.0,)), ("offset", 1, 0, ())]
    assert kinds[1].recall == 0.0
    assert percentile([4.0, 1.0, 3.0, 2.0], 50) == 2.0
    assert percentile([4.0, 1.0, 3.0, 2.0], 90) == 4.0
    assert percentile([4.0, 1.0, 3.0, 2.0], 0) == 1.0
    assert percentile([], 50) is None


def test_grace_must_be_a_non_negative_number() -> None:
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="grace"):
            score_run([], [], PUBLISHERS, start=0.0, end=1.0, grace=bad)
