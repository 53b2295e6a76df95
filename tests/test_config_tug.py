"""tug_observers configurations translate into native observer entries that mean the same.

The shared files are the TU Graz tool's own examples and templates
(/work/shared/compat/tug_observers) and the thesis experiment configurations
(/work/shared/reference/thesis-setup). Expected entries are written out by hand from the
tug files and docs/configuration.md. The last tests build the observers and compare what
they say they observe (``describe()``) across the two formats.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from blackbox.config.node import ConfigError
from blackbox.model import Resource
from blackbox.observe.build import build_observers, load_config

SHARED = Path("/work/shared")
TUG = SHARED / "compat" / "tug_observers"
THESIS = SHARED / "reference" / "thesis-setup"
NATIVE_THESIS = Path(__file__).parent / "data" / "configs" / "thesis_native.yaml"
THESIS_11_20 = THESIS / "observers_tests_11-20.yaml"

# file -> number of native observer entries it expands into
EXPECTED_COUNTS = {
    TUG / "observer_activated.yaml": 2,
    TUG / "observer_hz.yaml": 1,
    TUG / "observer_moveing.yaml": 1,
    TUG / "observer_resource.yaml": 2,
    TUG / "observer_template_activated.yaml": 1,
    TUG / "observer_template_config_hz.yaml": 1,
    TUG / "observer_template_config_scores.yaml": 1,
    TUG / "observer_template_config_timeout.yaml": 1,
    TUG / "observer_template_config_timestamp.yaml": 1,
    TUG / "observer_template_config_timing.yaml": 1,
    TUG / "observer_template_moveing.yaml": 0,
    TUG / "observer_template_resource.yaml": 1,
    TUG / "observer_template_velocity.yaml": 0,
    TUG / "observer_timeout.yaml": 2,
    TUG / "observer_timestamp.yaml": 1,
    TUG / "observer_timing.yaml": 1,
    TUG / "observer_velocity.yaml": 1,
    TUG / "setup_for_diagnosis.yaml": 4,
    THESIS / "fig6-1_partial_description.yaml": 1,
    THESIS / "observers_tests_01-10.yaml": 10,
    THESIS / "observers_tests_11-20.yaml": 10,
}


def entries(path: Path) -> list[dict[str, Any]]:
    return [e.to_python() for e in load_config(path).observers]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "tug.yaml"
    path.write_text(text)
    return path


def test_every_shared_observer_configuration_is_covered() -> None:
    shared = {*TUG.glob("*.yaml"), *THESIS.glob("observers_*.yaml"), *THESIS.glob("fig6-1*")}
    assert shared == set(EXPECTED_COUNTS)


@pytest.mark.parametrize("path", sorted(EXPECTED_COUNTS), ids=lambda p: p.name)
def test_shared_file_translates(path: Path) -> None:
    config = load_config(path)
    assert config.format == "tug"
    assert config.robot_id == "robot"
    assert len(config.observers) == EXPECTED_COUNTS[path]
    for entry in config.observers:
        assert entry.file == str(path)
        assert entry.line > 0


def test_thesis_11_20_is_the_native_thesis_file() -> None:
    assert entries(THESIS / "observers_tests_11-20.yaml") == entries(NATIVE_THESIS)


def test_thesis_hz_signal_keeps_its_period_in_seconds() -> None:
    hz = [e for e in entries(THESIS / "observers_tests_11-20.yaml") if e["type"] == "hz"]
    assert [e["topic"] for e in hz] == ["/audio", "/usb_cam/image_raw", "/signal"]
    signal = hz[2]
    assert signal == {
        "type": "hz", "topic": "/signal", "publishers": [], "every": 1.0,
        "filter": {"type": "mean", "window_size": 50, "deviation": "std_deviation"},
        "states": [{"number": 1, "name": "State_ok", "period": {
            "type": "nominal_value",
            "value": {"type": "gauss", "mean": 0.083333, "std_deviation": 0.01}}}],
    }


def test_frequenz_spelling_is_the_period_too() -> None:
    usb = entries(THESIS / "observers_tests_01-10.yaml")[2]
    assert usb["topic"] == "/usb_cam/image_raw"
    assert usb["states"][0]["period"]["value"]["mean"] == 0.06666666


def test_callerid_groups_expand_into_one_observer_each() -> None:
    assert entries(TUG / "observer_timeout.yaml") == [
        {"type": "timeout", "topic": "/topicA", "publishers": ["/dynamic_publisher"],
         "timeout": 1.0, "max_timeouts_in_a_row": 2},
        {"type": "timeout", "topic": "/topicA", "publishers": [],
         "timeout": 1.0, "max_timeouts_in_a_row": 2},
    ]


def test_activated_nodes_expand_and_keep_start_up_time() -> None:
    activated = entries(THESIS / "observers_tests_11-20.yaml")[4:7]
    assert activated == [
        {"type": "activated", "node": name, "start_up_time": 1.0}
        for name in ("/audio_capture", "/usb_cam", "/Signal_generator")]


def test_main_loop_rate_becomes_the_evaluation_interval(tmp_path: Path) -> None:
    path = write(tmp_path, """
setup:
  - type: scores
    main_loop_rate: 4
    topics:
      - name: /signal
""")
    assert entries(path) == [{"type": "scores", "topic": "/signal", "every": 0.25}]


def test_resources_rename_mem_filter() -> None:
    first = entries(TUG / "observer_resource.yaml")[0]
    assert first["node"] == "/robot_41/localize_to_target"
    assert first["cpu_filter"] == {"type": "mean", "window_size": 3}
    assert first["memory_filter"] == {"type": "median", "window_size": 3}
    assert first["states"][0]["memory"]["value"]["mean"] == 6512640


def test_timing_keys_take_native_names() -> None:
    [timing] = entries(TUG / "observer_timing.yaml")
    assert {k: timing[k] for k in ("topic_a", "publishers_a", "topic_b", "publishers_b",
                                   "single_shot", "every")} == {
        "topic_a": "/topicA", "publishers_a": [], "topic_b": "/topicB", "publishers_b": [],
        "single_shot": True, "every": 1.0}
    assert timing["filter"] == {"type": "ewma", "window_size": 10, "decay_rate": 0.05,
                                "deviation": "std_deviation"}
    assert timing["states"][0]["delay"]["deviation"] == [
        {"type": "in_between", "lower_bound": 0.0, "upper_bound": 0.5}]


def test_velocity_sources_and_moveing() -> None:
    [velocity] = entries(TUG / "observer_velocity.yaml")
    assert velocity["source_a"] == {"type": "odometry", "topic": "/robot_41/odom"}
    assert velocity["source_b"] == {"type": "twist", "topic": "/robot_41/cmd_vel"}
    assert set(velocity["states"][0]) == {"number", "name", "x", "y", "rot_x", "rot_y", "rot_z"}
    [moving] = entries(TUG / "observer_moveing.yaml")
    assert moving["type"] == "moving"
    assert moving["source"] == {"type": "imu", "topic": "/imu_data"}
    assert moving["x_filter"] == {"type": "nofilter"}


def test_tug_spellings_are_translated(tmp_path: Path) -> None:
    path = write(tmp_path, """
setup:
  - type: velocity
    correlations:
      - source_A: {type: twist, topic: /cmd_vel, acceleartion_window_size: 3}
        source_B: {type: imu, topic: /imu}
        use_yaw: false
        rot_z_filter: {type: median, window_size: 5, deviation_type: min_max}
        x_filter: {type: mean, window_size: 5, deviation_type: min_max}
        states:
          - state: 1
            number: 1
            x: {value: {type: greather_than, greater_than: -1.0}}
            rot_z: {value: {type: less_than, less_than: 1.0}}
""")
    [velocity] = entries(path)
    assert velocity["acceleration_window_size"] == 3
    assert velocity["x_filter"] == {"type": "mean", "window_size": 5, "deviation": "min_max"}
    assert velocity["use_yaw"] is False
    assert "rot_z_filter" not in velocity  # ignored by tug once rot_z is switched off
    assert velocity["states"] == [
        {"number": 1, "name": "1", "x": {"value": {"type": "greater_than", "greater_than": -1.0}}}]


def test_velocity_acceleration_window_defaults_to_tugs_seven() -> None:
    [velocity] = entries(TUG / "observer_velocity.yaml")  # odometry and twist, no window
    assert velocity["acceleration_window_size"] == 7


def test_velocity_sources_must_share_one_acceleration_window(tmp_path: Path) -> None:
    path = write(tmp_path, """
setup:
  - type: velocity
    correlations:
      - source_A: {type: twist, topic: /cmd_vel, acceleartion_window_size: 3}
        source_B: {type: odometry, topic: /odom}
""")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert (info.value.line, info.value.path) == (6, "setup[0].correlations[0].source_B")
    assert "source_A differentiates over 3 messages, source_B over 7" in info.value.message


def test_source_details_the_black_box_does_not_use_are_warned_about(tmp_path: Path) -> None:
    path = write(tmp_path, """
setup:
  - type: moveing
    moveings:
      - source: {type: odometry, topic: /odom, velocity_window_size: 3,
                 gravitation_cancelation: true}
""")
    config = load_config(path)
    assert [e.to_python() for e in config.observers] == [
        {"type": "moving", "source": {"type": "odometry", "topic": "/odom"}}]
    assert config.warnings == (
        f"{path}:5: at setup[0].moveings[0].source.velocity_window_size: ignored; "
        "the black box differentiates with its own window",
        f"{path}:6: at setup[0].moveings[0].source.gravitation_cancelation: ignored; "
        "gravitation is not cancelled",
    )


@pytest.mark.parametrize(("source", "message"), [
    ("{type: tf, base_frame: /a, target_frame: /b, topic: /tf}", "tf sources are not supported"),
    ("{type: imu, topic: /imu, x_filter: {type: mean, window_size: 3}}",
     "per-source filters are not supported"),
])
def test_unsupported_source_features_are_errors(tmp_path: Path, source: str,
                                                message: str) -> None:
    path = write(tmp_path, f"setup:\n  - type: moveing\n    moveings:\n      - source: {source}\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.line == 4
    assert message in info.value.message


def test_templates_load_with_empty_filters_and_checks() -> None:
    [hz] = entries(TUG / "observer_template_config_hz.yaml")
    assert hz["filter"] == {"type": "nofilter"}
    assert hz["states"] == [{"number": 1, "name": "state1", "period": {}}]
    [resources] = entries(TUG / "observer_template_resource.yaml")
    assert resources["memory_filter"] == {"type": "nofilter"}
    assert resources["states"][0]["cpu"] == {}


def test_template_sources_without_topic_warn_and_observe_nothing() -> None:
    path = TUG / "observer_template_velocity.yaml"
    config = load_config(path)
    assert config.observers == ()
    assert config.warnings[:2] == (
        f"{path}:35: at setup[0].correlations.source_A: template entry has no topic; "
        "it observes nothing until filled in",
        f"{path}:174: at setup[0].correlations.source_B: template entry has no topic; "
        "it observes nothing until filled in",
    )
    assert config.warnings[2].endswith("no observers; nothing will be observed")


def test_translated_nodes_point_into_the_original_file() -> None:
    path = THESIS / "observers_tests_11-20.yaml"
    signal_hz = load_config(path).observers[3]
    window = signal_hz["filter"]["window_size"]
    assert (window.file, window.line, window.path) == (
        str(path), 64, "setup[1].topics[2].callerids[0].filter.window_size")
    period = signal_hz["states"].list()[0]["period"]
    assert (period.line, period.path) == (
        70, "setup[1].topics[2].callerids[0].states[0].frequenzy")
    every = signal_hz["every"]
    assert (every.line, every.path) == (25, "setup[1].main_loop_rate")


@pytest.mark.parametrize(("text", "line", "path", "message"), [
    ("setup:\n  - type: hz\n    main_loop_rate: -1\n    topics: []\n",
     3, "setup[0].main_loop_rate", "must be > 0"),
    ("setup:\n  - type: hzz\n", 2, "setup[0].type", "did you mean 'hz'?"),
    ("setup:\n  - type: hz\n    topics:\n      - name: /a\n        callerid: []\n",
     5, "setup[0].topics[0].callerid", "did you mean 'callerids'?"),
    ("setup:\n  - type: hz\n    topics:\n      - name: /a\n        callerids: []\n",
     5, "setup[0].topics[0].callerids", "use '- callerid: []'"),
    ("setup:\n  - type: hz\n    topics:\n      - name: /a\n        callerids:\n"
     "          - callerid: []\n            states:\n              - state: ok\n"
     "                number: 1\n                frequenzy: {}\n                frequenz: {}\n",
     11, "setup[0].topics[0].callerids[0].states[0].frequenz", "mean the same"),
    ("setup:\n  - type: network\n", 2, "setup[0].type", "native format"),
    ("setup:\n  - type: scores\n    topics:\n      - name: /s\n        states:\n"
     "          - number: 1\n            score: {}\n",
     6, "setup[0].topics[0].states[0]", "missing required key 'state'"),
])
def test_tug_errors_name_the_original_place(tmp_path: Path, text: str, line: int, path: str,
                                            message: str) -> None:
    file = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(file)
    err = info.value
    assert (err.file, err.line, err.path) == (str(file), line, path)
    assert message in err.message


# ---- built observers ----------------------------------------------------------------------


def describe(path: Path) -> list[str]:
    return [o.describe() for o in build_observers(load_config(path))]


@pytest.mark.parametrize("path", sorted(EXPECTED_COUNTS), ids=lambda p: p.name)
def test_every_shared_file_builds(path: Path) -> None:
    observers = build_observers(load_config(path))
    assert len(observers) == EXPECTED_COUNTS[path]
    assert all(o.describe() for o in observers)


def test_tug_and_native_thesis_build_the_same_observers() -> None:
    tug = describe(THESIS_11_20)
    assert len(tug) == 10
    assert tug == describe(NATIVE_THESIS)


def test_thesis_observers_observe_the_thesis_robot() -> None:
    observers = build_observers(load_config(THESIS_11_20))
    assert [o.type_name for o in observers] == (
        ["scores"] + ["hz"] * 3 + ["activated"] * 3 + ["timeout"] * 3)
    hz_signal = observers[3]
    assert hz_signal.resource == Resource(topic="/signal", publishers=())
    assert "|value - 0.083333| < 0.01" in hz_signal.describe()
    assert [o.interval for o in observers[:4]] == [1.0] * 4
    assert [o.resource.node for o in observers[4:7]] == [
        "/audio_capture", "/usb_cam", "/Signal_generator"]


def test_callerid_groups_become_publisher_groups() -> None:
    first, second = build_observers(load_config(TUG / "observer_timeout.yaml"))
    assert first.resource == Resource(topic="/topicA", publishers=("/dynamic_publisher",))
    assert second.resource == Resource(topic="/topicA", publishers=())


def test_switched_off_rotation_is_not_observed(tmp_path: Path) -> None:
    path = tmp_path / "velocity.yaml"
    path.write_text("""
setup:
  - type: velocity
    correlations:
      - source_A: {type: odometry, topic: /odom}
        source_B: {type: twist, topic: /cmd_vel}
        use_yaw: false
        rot_z_filter: {type: mean, window_size: 5}
        states:
          - {state: still, number: 1, x: {value: {type: gauss, mean: 0, std_deviation: 0.1}},
             rot_z: {value: {type: gauss, mean: 0, std_deviation: 0.1}}}
""")
    [velocity] = build_observers(load_config(path))
    text = velocity.describe()
    assert "acceleration over 7 messages" in text
    assert "of rot_z" not in text


def test_unknown_observer_type_suggests_a_registered_one(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("observers:\n  - type: timestmap\n    topic: /a\n")
    config = load_config(path)
    with pytest.raises(ConfigError) as info:
        build_observers(config)
    assert (info.value.line, info.value.path) == (2, "observers[0].type")
    assert info.value.message == "unknown observer type 'timestmap'; did you mean 'timestamp'?"
