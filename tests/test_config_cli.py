"""``blackbox check-config`` through the real command line: a summary, or one located error.

Each bad file under tests/data/configs/bad/ has one mistake; the command must exit with 2 and
print exactly one line ``error: FILE:LINE:COL: at KEY.PATH: message``, never a traceback.
"""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
from pathlib import Path

import pytest

from blackbox.cli import main

pytestmark = pytest.mark.xdist_group("test_config_cli")  # its module fixture: one worker

DATA = Path(__file__).parent / "data" / "configs"
BAD = DATA / "bad"
THESIS = Path("/work/shared/reference/thesis-setup")
TUG = Path("/work/shared/compat/tug_observers")
ERROR_LINE = re.compile(
    r"^error: (?P<file>.+?):(?P<line>\d+):(?P<col>\d+):(?: at (?P<path>[^:]+):)? (?P<msg>.+)$")


def check_config(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackbox", "check-config", str(path)],
                          capture_output=True, text=True, timeout=60, check=False)


def check_config_here(path: Path) -> subprocess.CompletedProcess[str]:
    """``check-config`` through the same entry point in this process: what it prints and
    returns (a crash would raise here and fail the test). Each subprocess costs a second
    or more of imports; a few tests below keep the real process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["check-config", str(path)])
    return subprocess.CompletedProcess(["blackbox", "check-config", str(path)], code,
                                       out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def bad_results() -> dict[str, subprocess.CompletedProcess[str]]:
    """``check-config`` on every bad file."""
    names = sorted(p.name for p in BAD.glob("*.yaml"))
    return {n: check_config_here(BAD / n) for n in names}


def located_error(path: Path,
                  result: subprocess.CompletedProcess[str] | None = None) -> re.Match[str]:
    result = result or check_config(path)
    assert "Traceback" not in result.stderr
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    match = ERROR_LINE.match(lines[0])
    assert match, lines[0]
    assert match["file"] == str(path)
    return match


# file, line, key path (None: the error is about the whole document), part of the message
BAD_FILES = [
    ("yaml_syntax.yaml", 6, None, "invalid YAML: expected ',' or '}'"),
    ("tabs.yaml", 3, None, "invalid YAML: found character '\\t'"),
    ("empty.yaml", 1, None, "the file is empty; expected a top-level 'observers' list"),
    ("not_a_config.yaml", 2, None, "not a black box configuration"),
    ("duplicate_key.yaml", 6, "observers[0].timeout", "duplicate key 'timeout'"),
    ("unknown_top_level.yaml", 3, "obsevers", "unknown key 'obsevers'; did you mean 'observers'?"),
    ("unknown_observer_type.yaml", 3, "observers[0].type",
     "unknown observer type 'hzz'; did you mean 'hz'?"),
    ("key_typo.yaml", 7, "observers[0].filter.window_sise",
     "unknown key 'window_sise'; did you mean 'window_size'?"),
    ("negative_window.yaml", 5, "observers[0].filter.window_size", "got -5"),
    ("k_size_too_large.yaml", 8, "observers[0].filter.k_size",
     "k_size must be <= window_size (10), got 20"),
    ("string_for_number.yaml", 6, "observers[0].every", "expected a number, got str 'fast'"),
    ("missing_topic.yaml", 3, "observers[0]", "missing required key 'topic'"),
    ("unknown_filter_type.yaml", 5, "observers[0].filter.type",
     "unknown value 'meen'; expected one of ewma, kmeans, mean, median, nofilter; "
     "did you mean 'mean'?"),
    ("unknown_check_type.yaml", 9, "observers[0].states[0].score.value.type",
     "unknown value 'gaus'"),
    ("greather_than_native.yaml", 10, "observers[0].states[0].score.value.type",
     "did you mean 'greater_than'?"),
    ("bounds_reversed.yaml", 9, "observers[0].states[0].score.value.upper_bound",
     "must be greater than lower_bound"),
    ("same_characteristic_twice.yaml", 7, "observers[1]",
     "a second hz observer of /scan (the first is at line 4, observers[0]); their records "
     "would share one identity"),
    ("tug_zero_rate.yaml", 4, "setup[0].main_loop_rate", "must be > 0, got 0"),
    ("tug_unknown_type.yaml", 3, "setup[0].type", "did you mean 'timeout'?"),
    ("tug_window_typo.yaml", 11, "setup[0].topics[0].callerids[0].filter.window_sise",
     "did you mean 'window_size'?"),
]


def test_every_bad_file_is_in_the_table() -> None:
    names = {name for name, *_ in BAD_FILES} | {"duplicate_state_number.yaml"}
    assert {p.name for p in BAD.glob("*.yaml")} == names


@pytest.mark.parametrize(("name", "line", "path", "message"), BAD_FILES,
                         ids=[name for name, *_ in BAD_FILES])
def test_bad_configuration(bad_results: dict[str, subprocess.CompletedProcess[str]], name: str,
                           line: int, path: str | None, message: str) -> None:
    error = located_error(BAD / name, bad_results[name])
    assert int(error["line"]) == line
    assert error["path"] == path
    assert message in error["msg"]


def test_duplicate_state_number(bad_results: dict[str, subprocess.CompletedProcess[str]]) -> None:
    name = "duplicate_state_number.yaml"
    error = located_error(BAD / name, bad_results[name])
    assert (int(error["line"]), error["path"]) == (9, "observers[0].states[1].number")
    assert "duplicate state number 1" in error["msg"]


def test_missing_file_directory_and_garbage(tmp_path: Path) -> None:
    assert located_error(tmp_path / "absent.yaml")["msg"] == "file not found"
    assert "directory" in located_error(tmp_path)["msg"]
    garbage = tmp_path / "garbage.yaml"
    garbage.write_bytes(bytes(range(256)) * 4)
    assert "cannot read file" in located_error(garbage)["msg"]


def test_diagnosis_model_is_listed_not_observed() -> None:
    result = check_config(THESIS / "diagnosis_model.yaml")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].endswith("diagnosis model (not an observer configuration), "
                             "3 nodes, 8 observations")
    assert ("  /Signal_generator: subscribes [/usb_cam/image_raw, /audio], publishes [/signal]"
            in lines)
    assert "  activated: /audio_capture, /usb_cam, /Signal_generator" in lines


def test_thesis_configuration_summary() -> None:
    path = THESIS / "observers_tests_11-20.yaml"
    result = check_config(path)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == f"{path}: tug_observers format, robot 'robot', 10 observers"
    headings = [line for line in lines[1:] if not line.startswith("  ")]
    assert headings == ["scores (1):", "hz (3):", "activated (3):", "timeout (3):"]
    assert sum(line.startswith("  ") for line in lines) == 10


def test_a_template_that_observes_nothing_fails_as_run_would_and_shows_the_warnings() -> None:
    path = TUG / "observer_template_velocity.yaml"
    result = check_config(path)
    assert result.returncode == 2, result.stdout
    assert result.stderr.splitlines() == [
        f"warning: {path}:35: at setup[0].correlations.source_A: template entry has no topic; "
        "it observes nothing until filled in",
        f"warning: {path}:174: at setup[0].correlations.source_B: template entry has no topic; "
        "it observes nothing until filled in",
        f"warning: {path}:1: no observers; nothing will be observed",
        f"error: {path}:0:0: the configuration observes nothing",
    ]
