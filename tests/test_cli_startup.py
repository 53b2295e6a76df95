"""A ``blackbox`` command starts with only its own module: building every command's parser
imported numpy, Cyclone DDS and the learner at each start (about a second of CPU), which
tests, scripts and supervisors that start ``blackbox`` often paid again and again."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from blackbox.cli import command_module


@pytest.mark.parametrize(("argv", "module"), [
    (["check-config", "robot.yaml"], "check_config"),
    (["request-logs", "--help"], "request_logs"),
    (["run", "--source", "sim:thesis"], "run"),
    (["log", "query", "--db", "x.db"], "log"),
    (["--help"], None),          # options before a command: the full parser answers
    (["--version"], None),
    (["no-such-command"], None),  # argparse names the valid choices, as before
    ([], None),
])
def test_the_command_named_first_selects_the_one_module_to_load(
        argv: list[str], module: str | None) -> None:
    assert command_module(argv) == module


def _modules_after(argv: list[str]) -> set[str]:
    script = ("import json, sys\n"
              "from blackbox.cli import build_parser, command_module\n"
              f"build_parser(command_module({argv!r})).parse_args({argv!r})\n"
              "print(json.dumps(sorted(sys.modules)))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60, check=True)
    return set(json.loads(done.stdout))


def test_a_light_command_does_not_import_the_heavy_ones() -> None:
    loaded = _modules_after(["keygen", "station-a"])
    assert "blackbox.cli.keygen" in loaded
    assert not {"blackbox.learn", "blackbox.evaluate", "blackbox.cli.run", "numpy",
                "scipy"} & loaded


def test_an_unknown_command_is_still_refused_with_the_list_of_commands() -> None:
    done = subprocess.run([sys.executable, "-m", "blackbox", "no-such-command"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "invalid choice: 'no-such-command'" in done.stderr
    assert "check-config" in done.stderr and "run" in done.stderr
