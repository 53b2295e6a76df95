"""Loading a configuration is bounded: hostile files end in one located line, fast.

Each case is a file an attacker (or a careless copy) could hand to ``blackbox run`` or
``blackbox check-config``: billions of laughs, endless devices as the file or as a key file,
a huge file, deep nesting, an alias that contains itself. Each must end with exit code 2
and exactly one ``error: FILE:LINE:COL: ...`` line, never a traceback or a MemoryError,
and ``check-config`` must refuse exactly what ``run`` refuses.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from blackbox.cli import build_parser, main
from blackbox.config.node import ConfigNode

ERROR_LINE = re.compile(r"^error: (?P<file>.+?):(?P<line>\d+):(?P<col>\d+): (?P<msg>.+)$")
MAX_FILE_BYTES = 1024 * 1024
"""blackbox.config.node.MAX_FILE_BYTES, stated here so that this file also runs (and
fails) against a black box without the limits."""
HEADER = "robot:\n  id: ward-3\nobservers:\n  - type: hz\n    topic: /scan\n"


def blackbox(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackbox", *args], capture_output=True,
                          text=True, timeout=timeout, check=False)


def one_error_line(result: subprocess.CompletedProcess[str]) -> re.Match[str]:
    """The single located error line of a refused command (exit 2, no traceback)."""
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr[-2000:]
    match = ERROR_LINE.match(lines[0])
    assert match, lines[0]
    return match


def run_refuses(config: Path) -> re.Match[str]:
    return one_error_line(blackbox("run", "--config", str(config), "--duration", "1",
                                   "--simulated-clock", "--quiet"))


def billion_laughs(levels: int = 9) -> str:
    lines = ['lol0: &lol0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for level in range(1, levels):
        lines.append(f"lol{level}: &lol{level} [" + ",".join([f"*lol{level - 1}"] * 9) + "]")
    return "\n".join(f"  {line}" for line in lines)


def timed_load(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[re.Match[str], float]:
    """``check-config`` in this process: its one error line and the CPU seconds it took
    (CPU, not wall time: other tests share the machine; an unbounded load costs minutes of
    CPU, a bounded one milliseconds)."""
    build_parser()  # imports every command first: the time measured is the loading's
    capsys.readouterr()
    start = time.process_time()
    code = main(["check-config", str(path)])
    seconds = time.process_time() - start
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    match = ERROR_LINE.match(lines[0])
    assert match, lines[0]
    return match, seconds


def test_billion_laughs_under_an_unknown_key_is_refused_in_well_under_a_second(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "laughs.yaml"
    path.write_text(HEADER + "unknown_things:\n" + billion_laughs() + "\n")
    error, seconds = timed_load(path, capsys)
    assert "expands to more than" in error["msg"] and int(error["line"]) >= 6
    assert seconds < 0.5, f"took {seconds:.2f} s of CPU"
    assert "expands to more than" in run_refuses(path)["msg"]


@pytest.mark.parametrize("text, words", [
    ("a: &a [*a]\n", "an alias inside the value it names"),
    ("deep: " + "[" * 5000 + "]" * 5000 + "\n", "nested deeper than 64"),
])
def test_self_containing_aliases_and_deep_nesting_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, words: str) -> None:
    path = tmp_path / "nested.yaml"
    path.write_text(HEADER + text)
    error, seconds = timed_load(path, capsys)
    assert words in error["msg"] and int(error["line"]) >= 6, error[0]
    assert seconds < 0.5, f"took {seconds:.2f} s of CPU"


def test_a_huge_file_is_refused_before_it_is_parsed(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "huge.yaml"
    with path.open("w") as fh:
        fh.write(HEADER)
        for i in range(200_000):
            fh.write(f"  - {{type: hz, topic: /t{i}}}\n")
    assert path.stat().st_size > MAX_FILE_BYTES
    error, seconds = timed_load(path, capsys)
    assert "larger than 1,048,576 bytes" in error["msg"]
    assert seconds < 0.5, f"took {seconds:.2f} s of CPU"


def test_dev_zero_as_configuration_fault_schedule_or_key_file_is_one_line(
        tmp_path: Path) -> None:
    assert "not a regular file" in one_error_line(blackbox("check-config", "/dev/zero"))["msg"]
    assert "not a regular file" in run_refuses(Path("/dev/zero"))["msg"]
    config = tmp_path / "ok.yaml"
    config.write_text(HEADER)
    faults = one_error_line(blackbox("run", "--config", str(config), "--source", "sim:thesis",
                                     "--faults", "/dev/zero", "--duration", "1",
                                     "--simulated-clock", "--quiet"))
    assert faults["file"] == "/dev/zero" and "not a regular file" in faults["msg"]
    keyed = tmp_path / "keyed.yaml"
    keyed.write_text(HEADER + "transport:\n  access:\n    stations:\n"
                     "      - {name: depot, public_key_file: /dev/zero, may: [logs]}\n")
    for match in (one_error_line(blackbox("check-config", str(keyed))), run_refuses(keyed)):
        assert match["file"] == "/dev/zero", match[0]
        assert "not a regular file; a file named at transport.access.stations[0]" \
            ".public_key_file must be one" in match["msg"]


def test_a_key_file_too_large_is_refused(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    big = tmp_path / "station.pub"
    big.write_bytes(b"A" * (MAX_FILE_BYTES + 1))
    config = tmp_path / "keyed.yaml"
    config.write_text(HEADER + "transport:\n  access:\n    stations:\n"
                      "      - {name: depot, public_key_file: station.pub, may: [logs]}\n")
    error, _ = timed_load(config, capsys)
    assert error["file"] == str(big) and "larger than" in error["msg"]


@pytest.mark.parametrize("section, words", [
    ("transport:\n  domain_id: 99999\n", "at transport.domain_id: must be <= 232"),
    ("transport:\n  access:\n    stations:\n"
     "      - {name: depot, public_key: not-a-key, may: [logs]}\n", "transport.access"),
    ("recorder:\n  budgett: 1 GB\n", "unknown key 'budgett'"),
    ("robot:\n  id: ward-3\n  colour: red\n", "unknown key 'colour'"),
])
def test_check_config_refuses_exactly_what_run_refuses(tmp_path: Path, section: str,
                                                       words: str) -> None:
    text = HEADER.replace("robot:\n  id: ward-3\n", "") if section.startswith("robot") \
        else HEADER
    path = tmp_path / "config.yaml"
    path.write_text(text + section)
    checked = one_error_line(blackbox("check-config", str(path)))
    ran = run_refuses(path)
    assert checked[0] == ran[0]
    assert words in checked[0], checked[0]


def test_numbers_with_an_exponent_are_numbers(tmp_path: Path) -> None:
    root = ConfigNode.parse("tiny: 1e-300\nbig: 1E+3\nplain: 2.5e3\nname: e10\n")
    assert root["tiny"].float() == 1e-300
    assert root["big"].float() == 1000.0
    assert root["plain"].float() == 2500.0
    assert root["name"].str() == "e10"


def test_sigterm_ends_a_run_within_a_second_at_every_stage(tmp_path: Path) -> None:
    """SIGTERM at moments from interpreter start to a running pipeline: each run ends
    within a second of the signal, without a traceback."""
    config = tmp_path / "config.yaml"
    with config.open("w") as fh:  # a large, valid file: loading and building take a while
        fh.write("robot:\n  id: ward-3\nobservers:\n")
        for i in range(1500):
            fh.write(f"  - {{type: hz, topic: /t{i}}}\n")
    for delay in (0.2, 0.6, 1.0, 1.5, 2.0, 3.0, 4.5):
        process = subprocess.Popen(
            [sys.executable, "-m", "blackbox", "run", "--config", str(config), "--quiet",
             "--source", "sim:thesis"], stderr=subprocess.PIPE, text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            with contextlib.suppress(subprocess.TimeoutExpired):  # the moment varies
                process.wait(timeout=delay)
            assert process.returncode is None, process.stderr.read() if process.stderr else ""
            process.send_signal(signal.SIGTERM)
            signalled = time.monotonic()
            _, err = process.communicate(timeout=10)
            took = time.monotonic() - signalled
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        # Within a second on a quiet machine (docs/configuration.md); the bound leaves room
        # for parallel tests on two cores, and an ignored SIGTERM still fails it.
        assert took < 5.0, f"SIGTERM {delay} s after start took {took:.2f} s to end it"
        assert "Traceback" not in err, err[-2000:]
        assert process.returncode in (0, 143, -signal.SIGTERM), (delay, process.returncode,
                                                                  err[-500:])
