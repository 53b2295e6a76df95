"""SFDD (issue 18): the window judge, its variants, bad input, the engines on the pipeline."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from blackbox.app import RunOptions, build
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.diagnose.live import DiagnosisSettings
from blackbox.diagnose.sfdd import SfddDetector, SfddSettings
from blackbox.diagnose.sfdd_live import SfddConfig, SfddTap, SignalSpec
from blackbox.events import MessageArrival
from blackbox.model import Code, Diagnosis, Observation, Resource
from blackbox.sources.sim import Fault

CONFIG = Path(__file__).parents[1] / "src" / "blackbox" / "configs" / "diffdrive.yaml"
NAMES = ["a", "b", "c", "x", "y", "z"]


def motion(start: float = 0.0, seed: int = 1) -> np.ndarray:
    """Two independent motions, three sensors each (one of them inverted)."""
    t = np.arange(100) * 0.1 + start
    v = 0.3 + 0.4 * np.sin(2 * np.pi * t / 23) + 0.15 * np.sin(2 * np.pi * t / 7.1)
    w = 0.5 * np.sin(2 * np.pi * t / 17 + 1) + 0.2 * np.sin(2 * np.pi * t / 5.3)
    noise = np.random.default_rng(seed).normal(0, 0.02, (100, 6))
    return np.stack([v, 2 * v, v, w, w, -w], axis=1) + noise


def faulty(window: np.ndarray, settings: SfddSettings | None = None) -> set[str]:
    return {v.name for v in SfddDetector(NAMES, settings).judge(window) if v.faulty}


def patterns(window: np.ndarray, settings: SfddSettings | None = None) -> dict[str, str]:
    return {v.name: v.pattern for v in SfddDetector(NAMES, settings).judge(window)}


def test_correlated_healthy_signals_are_ok() -> None:
    assert patterns(motion()) == dict.fromkeys(NAMES, "ok")


def test_stuck_sensor_is_found_and_only_it() -> None:
    h = motion()
    h[50:, 2] = h[49, 2]
    p = patterns(h)
    assert p["c"] == "stuck"
    assert [n for n, v in p.items() if v != "ok"] == ["c"]


@pytest.mark.parametrize(("column", "change"), [
    (4, lambda col: col + 0.09 * np.arange(40) * 0.1 * 3),    # drift
    (2, lambda col: col + 0.15),                               # offset
    (4, lambda col: col * 1.5),                                # scale
])
def test_value_faults_on_one_correlated_sensor(column: int, change: object) -> None:
    h = motion()
    h[60:, column] = change(h[60:, column])  # type: ignore[operator]
    assert faulty(h) == {NAMES[column]}


def test_strict_mode_is_the_papers_stuck_and_drift_only() -> None:
    h = motion()
    h[70:, 2] += 0.15
    assert faulty(h, SfddSettings(strict=True)) == set()
    h = motion()
    h[50:, 2] = h[49, 2]
    assert faulty(h, SfddSettings(strict=True)) == {"c"}


def test_signed_variant_sees_a_sign_flip_the_absolute_value_hides() -> None:
    h = motion()
    h[50:, 5] = -h[50:, 5]   # z = -w becomes +w: |r| unchanged, sign flipped
    assert patterns(h, SfddSettings(strict=True))["z"] == "ok"
    assert patterns(h, SfddSettings(signed=True, strict=True))["z"] in ("uncertain", "drift")


def test_reference_variant_correlates_with_references_only() -> None:
    refs = SfddSettings(references=("a", "b", "x", "y"))
    verdicts = {v.name: v for v in SfddDetector(NAMES, refs).judge(motion())}
    assert set(verdicts["c"].peers) == {"a", "b"}
    assert set(verdicts["z"].peers) == {"x", "y"}
    h = motion()
    h[50:, 2] = h[49, 2]
    assert "c" in faulty(h, refs)


def test_change_variant_flags_a_correlation_change() -> None:
    h = motion()
    h[50:, 5] = -h[50:, 5]
    p = patterns(h, SfddSettings(change=True, strict=True))
    assert p["z"] in ("correlation_change", "drift")
    assert [n for n, v in p.items() if v != "ok"] == ["z"]


# ---- bad input --------------------------------------------------------------------------------

def test_window_shorter_than_configured_judges_nothing() -> None:
    out = SfddDetector(NAMES).judge(motion()[:40])
    assert {v.pattern for v in out} == {"unjudged"}
    assert "window not full (40 of 100" in out[0].reason


def test_constant_signal_is_unjudged_and_others_are_judged() -> None:
    h = motion()
    h[:, 1] = 5.0
    p = patterns(h)
    assert p["b"] == "unjudged"
    assert all(p[n] == "ok" for n in NAMES if n != "b")


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_rows_make_only_that_signal_unjudged(bad: float) -> None:
    h = motion()
    h[:30, 0] = bad
    p = patterns(h)
    assert p["a"] == "unjudged"
    assert all(p[n] == "ok" for n in NAMES if n != "a")


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="window"):
        SfddSettings(window=4)
    with pytest.raises(ValueError, match="correlation"):
        SfddSettings(correlation=1.5)
    with pytest.raises(ValueError, match="reference"):
        SfddDetector(NAMES, SfddSettings(references=("nope",)))


class _Msg:
    def __init__(self, data: float) -> None:
        self.data = data


def _arrival(t: float, topic: str, data: float) -> MessageArrival:
    msg = _Msg(data)
    return MessageArrival(t, topic, "/pub", 8, decode=lambda: msg)


def test_tap_drops_non_finite_values_and_a_late_signal_waits_for_a_full_window() -> None:
    config = SfddConfig((SignalSpec("/a"), SignalSpec("/b"), SignalSpec("/late")),
                        SfddSettings(window=20), period=0.1)
    tap = SfddTap(config)
    for k in range(60):
        t = 0.05 + 0.1 * k
        tap.on_message(_arrival(t, "/a", math.sin(t)))
        tap.on_message(_arrival(t, "/b", math.nan if k == 55 else 2 * math.sin(t)))
        if k >= 50:
            tap.on_message(_arrival(t, "/late", -math.sin(t)))
    obs = {o.resource.topic: o for o in tap.evaluate(6.0)}
    assert obs["/late"].code == Code.NOT_AVAILABLE
    assert obs["/b"].values["non_finite"] == 1.0
    assert obs["/a"].code != Code.NOT_AVAILABLE      # judged: it had a full fresh window


def test_tap_marks_a_silent_signal_unjudged() -> None:
    config = SfddConfig((SignalSpec("/a"), SignalSpec("/b")), SfddSettings(window=20))
    tap = SfddTap(config)
    for k in range(60):
        t = 0.05 + 0.1 * k
        tap.on_message(_arrival(t, "/a", math.sin(t)))
        if k < 40:
            tap.on_message(_arrival(t, "/b", math.sin(t)))
    codes = {o.resource.topic: o.code for o in tap.evaluate(6.0)}
    assert codes["/b"] == Code.NOT_AVAILABLE


# ---- configuration and engines on the pipeline ------------------------------------------------

def test_engine_without_signals_is_a_located_config_error(tmp_path: Path) -> None:
    node = ConfigNode.parse("engine: sfdd\n", str(tmp_path / "c.yaml"))
    with pytest.raises(ConfigError) as err:
        DiagnosisSettings.from_config(node, tmp_path)
    assert err.value.line == 1 and "sfdd.signals" in err.value.message


def test_unknown_engine_is_refused(tmp_path: Path) -> None:
    node = ConfigNode.parse("engine: magic\n", str(tmp_path / "c.yaml"))
    with pytest.raises(ConfigError):
        DiagnosisSettings.from_config(node, tmp_path)


class _Diagnoses:
    def __init__(self) -> None:
        self.diagnoses: list[Diagnosis] = []

    def on_observations(self, now: float, observations: object) -> None: ...
    def on_event(self, event: object) -> None: ...
    def close(self) -> None: ...

    def on_diagnosis(self, diagnosis: Diagnosis) -> None:
        self.diagnoses.append(diagnosis)


def _run(engine: str, fault: Fault) -> list[Diagnosis]:
    sink = _Diagnoses()
    box = build(RunOptions(config=CONFIG, source="sim:diffdrive", duration=40.0,
                           simulated_clock=True, faults=[fault], seed=3, live=False,
                           engine=engine, extra_sinks=[sink]))  # type: ignore[list-item]
    box.run()
    return sink.diagnoses


def test_sfdd_engine_names_the_stuck_odometry() -> None:
    diagnoses = _run("sfdd", Fault("stuck", "/odom", 20.0, 35.0))
    during = [d for d in diagnoses if 20.0 <= d.time <= 36.0 and d.candidates]
    assert during and all(d.engine == "sfdd" for d in diagnoses)
    assert any(d.candidates[0] & {"/odom", "/odometry"} for d in during)


def test_hybrid_records_agreement_and_sfdd_is_blind_to_a_kill() -> None:
    diagnoses = _run("hybrid", Fault("kill", "/camera", 20.0, 30.0))
    during = [d for d in diagnoses if 20.0 <= d.time <= 30.0 and d.candidates]
    assert during
    assert {d.engine for d in diagnoses} == {"hybrid"}
    assert any(d.agreement == "cbd only" and "/camera" in d.candidates[0] for d in during)
    assert diagnoses[-1].to_dict()["agreement"] == diagnoses[-1].agreement


def test_ucms_mapping_carries_sfdd_verdicts_and_the_engines_agreement() -> None:
    from blackbox.health.mapping import HealthMapper
    from blackbox.health.types import C_Failure_Event


    mapper = HealthMapper("r1", owners={"/odom": "/odometry"})
    obs = Observation(5.0, "sfdd:twist.twist.linear.x", Resource(topic="/odom"),
                      Code.NO_STATE_FITS, values={"shift_sigmas": 9.0},
                      message="stuck: no change while its correlated signals moved")
    mapper.start(0.0)
    assert mapper.observations(5.0, [obs])
    samples = mapper.diagnosis(Diagnosis(5.0, (frozenset({"/odometry"}),), (obs,),
                                         "[hybrid: agree] ...", True, "hybrid", "agree"))
    events = [s for s in samples if isinstance(s, C_Failure_Event)]
    assert len(events) == 1
    assert "engine hybrid (agree)" in events[0].A_complementaryInformation
    assert events[0].A_causeDescription.startswith("[hybrid: agree]")


def test_sfdd_is_blind_to_a_killed_sensor_node() -> None:
    diagnoses = _run("sfdd", Fault("kill", "/imu_driver", 20.0, 30.0))
    during = [d for d in diagnoses if 20.0 <= d.time <= 30.0 and d.candidates]
    assert not any(d.candidates[0] & {"/imu_driver", "/imu/data"} for d in during)


def test_evaluate_engine_scores_each_engine_on_the_same_campaign(
        capsys: pytest.CaptureFixture[str]) -> None:
    from blackbox.cli import main

    lines = {}
    for engine in ("cbd", "sfdd", "hybrid"):
        assert main(["evaluate", "--quiet", "--config", str(CONFIG), "--source",
                     "sim:diffdrive", "--runs", "1", "--duration", "60", "--kinds",
                     "stuck,kill", "--engine", engine]) == 0
        out = capsys.readouterr().out
        lines[engine] = next(line for line in out.splitlines() if line.startswith("engine "))
    assert lines["cbd"].startswith("engine cbd: diagnoses as detections: TP ")
    assert all("engine CPU" in line for line in lines.values())
    # same faults for every engine: the fault counts (TP + FN) agree
    def faults(line: str) -> int:
        words = line.replace(",", "").split()
        return int(words[words.index("TP") + 1]) + int(words[words.index("FN") + 1])
    assert faults(lines["cbd"]) == faults(lines["sfdd"]) == faults(lines["hybrid"]) > 0


def test_evaluate_engine_sfdd_on_a_robot_without_signals_is_a_usage_error(
        capsys: pytest.CaptureFixture[str]) -> None:
    from blackbox.cli import main

    assert main(["evaluate", "--quiet", "--runs", "1", "--duration", "30",
                 "--engine", "sfdd"]) == 2
    assert "needs diagnosis.sfdd.signals" in capsys.readouterr().err


def _hybrid(mode: str, cbd_failed: Observation, sfdd_code: Code) -> Diagnosis:
    from blackbox.diagnose.hybrid import CbdDiagnoser, HybridDiagnoser
    from blackbox.diagnose.sfdd_live import SfddDiagnoser

    config = SfddConfig((SignalSpec("/odom", "twist.twist.linear.x", "/odometry"),
                         SignalSpec("/cmd_vel", "linear.x", "/teleop")))
    hybrid = HybridDiagnoser(CbdDiagnoser([], DiagnosisSettings()), SfddDiagnoser(config), mode)
    hybrid.cbd.current = Diagnosis(9.0, (frozenset({"/odometry"}),), (cbd_failed,), "cbd")
    hybrid.sfdd.feed([
        Observation(9.0, "sfdd:twist.twist.linear.x", Resource(topic="/odom"), sfdd_code),
        Observation(9.0, "sfdd:linear.x", Resource(topic="/cmd_vel"), Code.GENERAL_OK)])
    return hybrid.combine(10.0)


VALUE_ALARM = Observation(9.0, "scores", Resource(topic="/odom"), Code.NO_STATE_FITS)
RATE_ALARM = Observation(9.0, "timeout", Resource(topic="/odom"), Code.TIMEOUT)


def test_hybrid_confirms_a_cbd_candidate_sfdd_also_blames() -> None:
    d = _hybrid("rank", VALUE_ALARM, Code.NO_STATE_FITS)
    assert d.agreement == "agree" and d.candidates[0] == frozenset({"/odometry"})


def test_hybrid_rank_keeps_a_questioned_candidate_and_verify_withholds_it() -> None:
    ranked = _hybrid("rank", VALUE_ALARM, Code.GENERAL_OK)
    assert ranked.agreement == "questioned by sfdd"
    assert ranked.candidates == (frozenset({"/odometry"}),)
    verified = _hybrid("verify", VALUE_ALARM, Code.GENERAL_OK)
    assert verified.agreement == "withheld: sfdd questions cbd" and verified.candidates == ()


def test_hybrid_verify_never_withholds_an_alarm_sfdd_cannot_see() -> None:
    d = _hybrid("verify", RATE_ALARM, Code.GENERAL_OK)
    assert d.candidates == (frozenset({"/odometry"}),)


def test_hybrid_unjudged_signal_leaves_cbd_alone() -> None:
    d = _hybrid("rank", VALUE_ALARM, Code.NOT_AVAILABLE)
    assert d.agreement == "cbd only"


def test_persistence_reports_a_pattern_only_after_k_windows_in_a_row() -> None:
    config = SfddConfig((SignalSpec("/a"), SignalSpec("/b"), SignalSpec("/c")),
                        SfddSettings(window=40), period=0.1, persistence=2)
    tap = SfddTap(config)
    codes = []
    for k in range(100):
        t = 0.05 + 0.1 * k
        x = math.sin(t) + 0.01 * math.cos(37 * t)
        tap.on_message(_arrival(t, "/a", x))
        tap.on_message(_arrival(t, "/b", 2 * x + 0.01 * math.sin(53 * t)))
        tap.on_message(_arrival(t, "/c", x if t < 7.0 else 0.5))   # stuck from 7 s
        if k % 5 == 4:
            codes.append({o.resource.topic: o for o in tap.evaluate(t + 0.05)}["/c"])
    faulty_at = [i for i, o in enumerate(codes) if o.code == Code.NO_STATE_FITS]
    suspect_at = [i for i, o in enumerate(codes) if o.message.startswith("suspect")]
    assert faulty_at and suspect_at and suspect_at[0] == faulty_at[0] - 1


def test_a_long_gap_in_the_source_costs_one_window_not_the_gap() -> None:
    config = SfddConfig((SignalSpec("/a"), SignalSpec("/b")), SfddSettings(window=20))
    tap = SfddTap(config)
    tap.on_message(_arrival(0.0, "/a", 1.0))
    tap.on_message(_arrival(1e7, "/a", 2.0))        # 116 days later: 1e8 ticks if walked
    obs = tap.evaluate(1e7 + 0.5)
    assert {o.code for o in obs} == {Code.NOT_AVAILABLE}
    assert tap.window().shape == (20, 2)


def test_recorder_logs_the_engine_and_the_agreement(tmp_path: Path) -> None:
    from blackbox.record import Recorder, Store
    from blackbox.record.settings import RecorderSettings

    rec = Recorder(RecorderSettings(tmp_path / "log.db", commit_interval=0.05, snapshot=None),
                   robot_id="r1")
    rec.on_diagnosis(Diagnosis(1_700_000_001.0, (frozenset({"/odometry"}),), (),
                               "[hybrid: agree] ...", True, "hybrid", "agree"))
    rec.close()
    with Store.open(tmp_path / "log.db", readonly=True) as store:
        (row,) = list(store.query(kinds=["diagnosis"]))
    assert (row.payload["engine"], row.payload["agreement"]) == ("hybrid", "agree")
