"""Format detection, the native top level, diagnosis models and unreadable files."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from blackbox.config.loader import (
    ModelNode,
    ModelObservation,
    document_kind,
    outline_diagnosis_model,
    read_document,
)
from blackbox.config.node import ConfigError
from blackbox.observe.build import build_observers, load_config

DATA = Path(__file__).parent / "data" / "configs"
THESIS_MODEL = Path("/work/shared/reference/thesis-setup/diagnosis_model.yaml")
TUG_DIAGNOSIS = Path("/work/shared/compat/tug_diagnosis")


def write(tmp_path: Path, text: str | bytes, name: str = "config.yaml") -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


def load_error(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return info.value


def test_native_thesis_file() -> None:
    config = load_config(DATA / "thesis_native.yaml")
    assert config.format == "native"
    assert config.robot_id == "thesis-robot"
    assert [e["type"].raw for e in config.observers] == (
        ["scores"] + ["hz"] * 3 + ["activated"] * 3 + ["timeout"] * 3)
    assert list(config.sections) == ["robot"]
    assert config.warnings == ()


def test_native_sections_are_kept_for_their_stages(tmp_path: Path) -> None:
    path = write(tmp_path, """
version: 1
observers: [{type: activated, node: /a}]
diagnosis: {model: thesis}
recorder: {directory: /tmp/x}
transport: {}
station: {}
faults: []
""")
    error = load_error(path)  # faults must be a mapping like every section
    assert (error.line, error.path) == (8, "faults")
    path.write_text(path.read_text().replace("faults: []", "faults: {}"))
    config = load_config(path)
    assert list(config.sections) == ["diagnosis", "recorder", "transport", "station", "faults"]
    assert config.sections["recorder"]["directory"].raw == "/tmp/x"
    assert config.robot_id == "robot"


def test_native_file_without_observers_warns(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, "robot: {id: r7}\nstation: {port: 1}\n"))
    assert config.observers == ()
    assert config.robot_id == "r7"
    assert config.warnings == (f"{tmp_path / 'config.yaml'}:1: no observers; "
                               "nothing will be observed",)


@pytest.mark.parametrize(("text", "line", "path", "message"), [
    ("observers: []\nsetup: []\n", 1, "observers", "not both"),
    ("version: 2\nobservers: []\n", 1, "version", "unsupported format version 2"),
    ("observers: {type: hz}\n", 1, "observers", "expected a list of observer entries"),
    ("observers:\n  - topic: /a\n", 2, "observers[0]", "missing required key 'type'"),
    ("observers:\n  - hz\n", 2, "observers[0]", "expected an observer entry"),
    ("robot: {id: 7}\nobservers: []\n", 1, "robot.id", "expected a non-empty string"),
    ("observers: []\nrecorder: 5\n", 2, "recorder", "must be a mapping"),
    ("observers: []\nstaton: {}\n", 2, "staton", "did you mean 'station'?"),
    ("- type: hz\n", 1, "", "not a configuration"),
    ("just text\n", 1, "", "not a configuration"),
    ("hello: world\n", 1, "", "not a black box configuration"),
    ("observer: []\n", 1, "observer", "did you mean 'observers'?"),
    ("observers: !foo bar\n", 1, "", "invalid YAML"),
    ("observers: !!python/object/apply:os.system echo\n", 1, "", "invalid YAML"),
])
def test_malformed_files_are_config_errors(tmp_path: Path, text: str, line: int, path: str,
                                           message: str) -> None:
    error = load_error(write(tmp_path, text))
    assert (error.line, error.path) == (line, path)
    assert message in error.message


def test_unreadable_inputs(tmp_path: Path) -> None:
    assert load_error(tmp_path / "absent.yaml").message == "file not found"
    assert "directory" in load_error(tmp_path).message
    assert "empty" in load_error(write(tmp_path, "")).message
    assert "empty" in load_error(write(tmp_path, "# only a comment\n")).message
    assert "cannot read file" in load_error(write(tmp_path, b"\xff\xfe\x00garbage\x81")).message
    assert "invalid YAML" in load_error(write(tmp_path, b"observers: [\x00]\n")).message


def test_diagnosis_models_are_recognised() -> None:
    for path in (THESIS_MODEL, *sorted(TUG_DIAGNOSIS.glob("*.yaml"))):
        assert document_kind(read_document(path)) == "diagnosis"
        error = load_error(path)
        assert "diagnosis model" in error.message


def test_diagnosis_model_outline() -> None:
    model = outline_diagnosis_model(read_document(THESIS_MODEL))
    assert model.nodes == (
        ModelNode("/usb_cam", (), ("/usb_cam/image_raw",)),
        ModelNode("/audio_capture", (), ("/audio",)),
        ModelNode("/Signal_generator", ("/usb_cam/image_raw", "/audio"), ("/signal",)),
    )
    assert model.observations[0] == ModelObservation(
        "activated", ("/audio_capture", "/usb_cam", "/Signal_generator"))
    assert [o.type for o in model.observations] == (
        ["activated"] + ["hz"] * 3 + ["timeout"] * 3 + ["scores"])


def test_mutated_configurations_fail_only_with_config_errors(tmp_path: Path) -> None:
    """Seeded random edits of the shared files: every outcome is a result or a ConfigError."""
    sources = sorted([*Path("/work/shared/compat/tug_observers").glob("*.yaml"),
                      *THESIS_MODEL.parent.glob("*.yaml"), DATA / "thesis_native.yaml"])
    values = ["-1", "0", "1.5", "null", "[]", "{}", "abc", "1e400", ".nan", "true", "[a, b]",
              "{a: 1}", "99999999999999999999", "!!binary aGVsbG8=", "2020-01-01", "/x",
              "{type: kmeans, window_size: 2, k_size: 3}", "{type: gauss}"]
    rng = random.Random(20240601)
    path = tmp_path / "mutated.yaml"
    outcomes = {"loaded": 0, "error": 0}
    for _ in range(300):
        lines = rng.choice(sources).read_text().splitlines()
        for _ in range(rng.randint(1, 3)):
            j = rng.randrange(len(lines))
            line = lines[j]
            if ":" in line and rng.random() < 0.7:
                lines[j] = line[:line.index(":") + 1] + " " + rng.choice(values)
            elif rng.random() < 0.5:
                lines[j] = line[:rng.randrange(len(line) + 1)]
            else:
                lines[j] = " " * rng.randint(0, 4) + line.lstrip()
        path.write_text("\n".join(lines) + "\n")
        try:
            root = read_document(path)
            if document_kind(root) == "diagnosis":
                outline_diagnosis_model(root)
            else:
                for observer in build_observers(load_config(path)):
                    observer.describe()
            outcomes["loaded"] += 1
        except ConfigError as exc:
            assert exc.file == str(path)
            outcomes["error"] += 1
    assert outcomes["loaded"] > 0 and outcomes["error"] > 0
