"""The UCMS mapping, status rules and source ids, without a network."""

from __future__ import annotations

import math

import pytest

from blackbox.config.node import ConfigNode
from blackbox.health.describe import ThresholdSpec, describe_observer
from blackbox.health.extension import C_Characteristic_Extension, C_Event_Extension, T_EventKind
from blackbox.health.ids import SourceIds, stable_int
from blackbox.health.mapping import FailureActions, HealthMapper
from blackbox.health.status import FAILING, OK, UNKNOWN, CharacteristicStatus, Health, Hysteresis
from blackbox.health.types import (
    C_Failure_Event,
    C_Monitored_Characteristic,
    C_Monitored_Characteristic_Specification,
    C_Monitored_Entity,
    C_Threshold,
    C_Threshold_Exceedence_Event,
    T_HealthStatus,
    T_ThresholdType,
    datetime_of,
    seconds_of,
)
from blackbox.model import Code, Diagnosis, Observation, Resource, State

CAMERA = Resource(topic="/usb_cam/image_raw", publishers=("/usb_cam",))
HZ_CONFIG = """
type: hz
topic: /usb_cam/image_raw
publishers: [/usb_cam]
every: 0.5
filter: {type: mean, window_size: 50}
states:
  - {number: 1, name: ok, period: {value: {type: gauss, mean: 0.0667, std_deviation: 0.01}}}
  - {number: 2, name: slow, period: {value: {type: in_between, lower_bound: 0.05,
                                             upper_bound: 0.2}}}
"""


def of(samples, kind):
    return [s for s in samples if isinstance(s, kind)]


def obs(t, code=Code.GENERAL_OK, period=0.0667, states=("ok",)):
    return Observation(t, "hz", CAMERA, code, tuple(State(i + 1, n) for i, n in enumerate(states)),
                       {"period": period})


def test_ids_are_stable_and_robot_scoped():
    a, b = SourceIds("thesis"), SourceIds("thesis")
    assert a.of("entity", "/usb_cam") == b.of("entity", "/usb_cam")
    assert a.of("entity", "/usb_cam") != a.of("entity", "/audio_capture")
    assert SourceIds("other").of("entity", "/usb_cam").A_resourceId != a.resource_id
    assert stable_int("robot", "thesis") == a.resource_id
    assert 0 < a.resource_id < 2**31


def test_datetime_round_trip():
    dt = datetime_of(1700000000.25)
    assert (dt.A_second, dt.A_nanoseconds) == (1700000000, 250_000_000)
    assert seconds_of(dt) == 1700000000.25


def test_thresholds_are_the_envelope_of_the_states():
    d = describe_observer(ConfigNode.parse(HZ_CONFIG))
    assert d.interval == 0.5
    # ok: 0.0567..0.0767, slow: 0.05..0.2 -> any state fits in 0.05..0.2
    assert d.thresholds == (ThresholdSpec("period", "min", 0.05),
                            ThresholdSpec("period", "max", 0.2))
    assert d.expected_noise == {"period": 0.01}
    assert d.filter_type == "mean" and d.filter_parameters == {"window_size": 50.0}
    assert d.states == ("ok", "slow")


def test_node_observer_and_thresholds_map_to_ucms():
    d = describe_observer(ConfigNode.parse(HZ_CONFIG))
    m = HealthMapper("thesis", descriptions=[d])
    out = m.start(0.0) + m.observations(1.0, [obs(1.0)])
    entity_ids = {s.A_sourceID.A_instanceId for s in of(out, C_Monitored_Entity)}
    assert m.ids.of("entity", "/usb_cam").A_instanceId in entity_ids  # node via its publisher
    spec = of(out, C_Monitored_Characteristic_Specification)[0]
    assert (spec.A_unit, spec.A_publishingIntervalInSeconds) == ("s", 1)
    assert spec.A_descriptor == "hz /usb_cam/image_raw [/usb_cam] period"
    thresholds = {(t.A_type, t.A_value) for t in of(out, C_Threshold)}
    assert thresholds == {(T_ThresholdType.L_ThresholdType_MIN, 0.05),
                          (T_ThresholdType.L_ThresholdType_MAX, 0.2)}
    ext = of(out, C_Characteristic_Extension)[0]
    assert (ext.A_expectedNoise, ext.A_filterType, ext.A_evaluationIntervalInSeconds) == (
        0.01, "mean", 0.5)
    value = of(out, C_Monitored_Characteristic)[0]
    assert value.A_value == 0.0667
    last = of(out, C_Monitored_Entity)[-1]
    assert last.A_healthStatus == T_HealthStatus.L_HealthStatus_OPERATIONAL


def test_failed_observation_is_one_exceedence_at_its_onset():
    d = describe_observer(ConfigNode.parse(HZ_CONFIG))
    m = HealthMapper("thesis", descriptions=[d])
    m.observations(1.0, [obs(1.0)])
    first = m.observations(2.0, [obs(2.0, Code.NO_STATE_FITS, 0.5, ())])
    again = m.observations(3.0, [obs(3.0, Code.NO_STATE_FITS, 0.6, ())])
    [event] = of(first, C_Threshold_Exceedence_Event)
    assert event.A_measuredValue == 0.5
    assert event.A_exceededThreshold_sourceID == m.ids.of(
        "threshold", "hz", event_key(), "period", "max")
    assert of(first, C_Event_Extension)[0].A_kind == T_EventKind.L_EventKind_FAULT
    assert of(again, C_Threshold_Exceedence_Event) == []
    assert of(again, C_Monitored_Characteristic)[0].A_thresholdExceedenceEvents_sourceID == [
        event.A_sourceID]


def event_key():
    from blackbox.health.mapping import resource_key

    return resource_key(CAMERA)


def test_state_change_is_told_apart_from_a_fault():
    m = HealthMapper("thesis")
    m.observations(1.0, [obs(1.0, states=("ok",))])
    out = m.observations(2.0, [obs(2.0, period=0.15, states=("slow",))])
    [ext] = of(out, C_Event_Extension)
    assert ext.A_kind == T_EventKind.L_EventKind_STATE_CHANGE
    assert (ext.A_fromStates, ext.A_toStates) == (["ok"], ["slow"])
    assert m.entities()["/usb_cam"] == Health.OPERATIONAL


def test_diagnosis_becomes_a_failure_event_with_configured_actions():
    actions = {"/usb_cam": FailureActions("no video", "stop the robot", "replug the camera")}
    m = HealthMapper("thesis", failure_actions=actions)
    m.observations(1.0, [obs(1.0)])
    bad = obs(2.0, Code.TIMEOUT, 9.0, ())
    m.observations(2.0, [bad])
    out = m.diagnosis(Diagnosis(2.0, (frozenset({"/usb_cam"}), frozenset({"/x"})), (bad,),
                                "camera silent"))
    [f] = of(out, C_Failure_Event)
    assert f.A_failureDescription == "/usb_cam diagnosed faulty (best of 2 candidate explanations)"
    assert f.A_causeDescription == "camera silent"
    assert (f.A_operationalConsequenceDescription, f.A_operatorActionDescription,
            f.A_maintenanceActionDescription) == ("no video", "stop the robot", "replug the camera")
    assert (f.A_standardFaultCode, f.A_proprietaryFaultCode) == (-4.0, "TIMEOUT")
    assert f.A_monitoredEntity_sourceID == m.ids.of("entity", "/usb_cam")
    entity = [s for s in of(out, C_Monitored_Entity)
              if s.A_sourceID == f.A_monitoredEntity_sourceID]
    assert entity[-1].A_failureEvents_sourceID == [f.A_sourceID]
    assert entity[-1].A_healthStatus == T_HealthStatus.L_HealthStatus_NOT_OPERATIONAL
    # The same diagnosis again is no new failure event; a clean one clears the entity.
    assert of(m.diagnosis(Diagnosis(3.0, (frozenset({"/usb_cam"}),))), C_Failure_Event) == []
    m.diagnosis(Diagnosis(4.0, ()))
    assert m.entities()["/usb_cam"] == Health.NOT_OPERATIONAL  # its only characteristic fails


def test_hysteresis_keeps_a_wobbling_signal_failing():
    s = CharacteristicStatus(Hysteresis(raise_after=1, clear_after=3), interval=1.0)
    verdicts = [False, True, False, True, False, False, False]
    states = []
    for t, faulty in enumerate(verdicts):
        s.update(float(t), faulty)
        states.append(s.state)
    assert states == [OK, FAILING, FAILING, FAILING, FAILING, FAILING, OK]
    assert s.expire(6.0 + 3.5)  # silent for more than 3 intervals
    assert s.state == UNKNOWN


def test_entity_and_robot_rules():
    m = HealthMapper("thesis", hysteresis=Hysteresis(clear_after=1))
    audio = Resource(topic="/audio", publishers=("/audio_capture",))
    m.observations(1.0, [obs(1.0), Observation(1.0, "hz", audio, Code.GENERAL_OK)])
    assert m.entities() == {"": Health.OPERATIONAL, "/usb_cam": Health.OPERATIONAL,
                            "/audio_capture": Health.OPERATIONAL}
    m.observations(2.0, [obs(2.0, Code.NO_STATE_FITS), Observation(2.0, "hz", audio,
                                                                    Code.NOT_AVAILABLE)])
    assert m.entities() == {"": Health.NOT_OPERATIONAL, "/usb_cam": Health.NOT_OPERATIONAL,
                            "/audio_capture": Health.UNKNOWN}


def test_observer_without_values_is_a_code_characteristic():
    m = HealthMapper("thesis")
    out = m.observations(1.0, [Observation(1.0, "activated", Resource(node="/usb_cam"),
                                           Code.GENERAL_ERROR, message="node dead")])
    [c] = of(out, C_Monitored_Characteristic)
    assert c.A_value == -1.0
    [t] = of(out, C_Threshold)
    assert (t.A_type, t.A_value) == (T_ThresholdType.L_ThresholdType_MIN, 0.0)
    [e] = of(out, C_Threshold_Exceedence_Event)
    assert e.A_exceededThreshold_sourceID == t.A_sourceID


def test_non_finite_values_are_not_published():
    m = HealthMapper("thesis")
    out = m.observations(1.0, [obs(1.0, period=math.nan)])
    assert of(out, C_Monitored_Characteristic) == []


def test_bad_transport_config_is_a_located_error():
    from blackbox.config.node import ConfigError
    from blackbox.transport.publisher import transport_options

    with pytest.raises(ConfigError, match="did you mean 'partition'"):
        transport_options(ConfigNode.parse("domain_id: 3\npartiton: x\n"))
    with pytest.raises(ConfigError, match="must be <= 232"):
        transport_options(ConfigNode.parse("domain_id: 999\n"))
    opts = transport_options(ConfigNode.parse(
        "domain_id: 3\nowners: {/usb_cam: [/usb_cam/image_raw]}\nstatus: {clear_after: 5}\n"))
    assert opts["domain_id"] == 3 and opts["owners"] == {"/usb_cam/image_raw": "/usb_cam"}
    assert opts["hysteresis"] == Hysteresis(clear_after=5)
