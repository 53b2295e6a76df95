"""Every command the documentation shows is one the code accepts.

A reader copies commands from README.md and docs/*.md; a renamed option or a moved file
makes them fail long after the change that broke them. This test takes every shell command
in those files' code blocks that starts with ``blackbox``, ``.venv/bin/blackbox``,
``.venv/bin/python benchmarks/...`` or ``make`` and checks, without running anything long:

* a ``blackbox`` command names subcommands that exist and long options their parsers
  accept (the parsers are built from :func:`blackbox.cli.build_parser`, nothing runs);
* a benchmark command names a script that exists, and options its ``--help`` lists
  (one fast subprocess per script and subcommand; a script without argparse takes none);
* a ``make`` command names targets of the Makefile;
* every path a command names under a directory of the repository exists;
* the short commands that need no robot (:data:`RUN_HERE`) run here and exit with 0.

A wrong command is fixed in the documentation, never by widening this test.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

from blackbox.cli import build_parser, main

ROOT = Path(__file__).resolve().parent.parent
DOCUMENTS = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))

#: Top-level entries of the repository: a path starting with one of them is inside it.
REPOSITORY_ROOTS = frozenset({"src", "data", "docs", "benchmarks", "scripts", "tests", ".ci",
                              "Makefile", "README.md", "CHANGELOG.md", "pyproject.toml"})

#: ``blackbox`` subcommand paths whose documented examples are short and need no robot,
#: no network and no files but the repository's: they are run, and must exit with 0.
RUN_HERE = frozenset({("check-config",), ("dxc",), ("log", "capacity")})

#: Arguments of examples that are short to read but take 5-20 s here (the 160-gate c432
#: circuit, the 74181 audit, an hour of a 250-observer robot): checked, not run.
LONG_EXAMPLES = frozenset({"c432", "74181", "100-topic"})

#: Words a documented command may start with that are not part of the command itself.
PREFIXES = frozenset({"$", "sudo", "time"})

COMMAND_START = re.compile(r"^(\$\s+)?(sudo\s+)?(time\s+)?"
                           r"(blackbox\b|\.venv/bin/blackbox\b|\.venv/bin/python\s+benchmarks/"
                           r"|make\b)")
SYNOPSIS_MARKS = "[]()"
FILE_SUFFIXES = (".yaml", ".yml", ".json", ".jsonl", ".db", ".bag", ".mcap", ".py", ".md",
                 ".key", ".pub", ".pem", ".csv", ".sh")


@dataclass(frozen=True)
class DocCommand:
    """One shell command shown in a code block of a document."""

    document: Path
    line: int
    text: str
    argv: tuple[str, ...]

    @property
    def where(self) -> str:
        return f"{self.document.relative_to(ROOT)}:{self.line}"

    @property
    def program(self) -> str:
        return self.argv[0]

    @property
    def arguments(self) -> tuple[str, ...]:
        """The words after the program (after the script for a benchmark)."""
        return self.argv[2:] if self.program.endswith("python") else self.argv[1:]


def _code_lines(text: str) -> Iterator[tuple[int, str]]:
    """Lines inside fenced code blocks, and indented code blocks after a blank line."""
    fenced = False
    indented = False
    previous_blank = True
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped.startswith(("```", "~~~")):
            fenced = not fenced
            previous_blank = False
            continue
        if fenced:
            yield number, line
        else:
            starts_block = line.startswith("    ") and stripped and previous_blank
            indented = bool(stripped) and (starts_block or (indented and line.startswith("    ")))
            if indented:
                yield number, line
        previous_blank = not stripped


def _commands_of(document: Path) -> Iterator[DocCommand]:
    lines = list(_code_lines(document.read_text(encoding="utf-8")))
    index = 0
    while index < len(lines):
        number, line = lines[index]
        text = line.strip()
        if COMMAND_START.match(text):
            while text.endswith("\\") and index + 1 < len(lines):
                index += 1
                text = text[:-1].rstrip() + " " + lines[index][1].strip()
            words = [w for w in shlex.split(text, comments=True)]
            while words and (words[0] in PREFIXES or re.fullmatch(r"[A-Z_]+=\S*", words[0])):
                words.pop(0)
            yield DocCommand(document, number, text, tuple(words))
        index += 1


def documented_commands() -> list[DocCommand]:
    return [c for d in DOCUMENTS for c in _commands_of(d)]


COMMANDS = documented_commands()
BLACKBOX = [c for c in COMMANDS if c.program in ("blackbox", ".venv/bin/blackbox")]
BENCHMARKS = [c for c in COMMANDS if c.program.endswith("python")]
MAKE = [c for c in COMMANDS if c.program == "make"]


def _ids(commands: list[DocCommand]) -> list[str]:
    return [c.where for c in commands]


# --- blackbox: subcommands and options, from the real parsers --------------------------------

def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _unmark(word: str) -> str:
    """A word of a synopsis (``[--since T]``, ``(--config FILE``) without its brackets."""
    return word.strip(SYNOPSIS_MARKS)


@dataclass(frozen=True)
class ParsedCommand:
    """A documented ``blackbox`` command as its parsers read it."""

    subcommand: tuple[str, ...]
    errors: tuple[str, ...]


@cache
def blackbox_parser() -> argparse.ArgumentParser:
    """The command line's parser, built once (it is only read here)."""
    return build_parser()


def parse_blackbox(command: DocCommand) -> ParsedCommand:
    """Walk ``command``'s words through the real parsers: subcommand names descend, options
    must be known to the parser they are given to, and an option's value is skipped."""
    parser = blackbox_parser()
    path: list[str] = []
    errors: list[str] = []
    words = [_unmark(w) for w in command.arguments]
    index = 0
    while index < len(words):
        word = words[index]
        index += 1
        if not word or word == "|" or word == "...":
            continue
        if word.startswith("-") and not re.fullmatch(r"-\d[\d.]*", word):
            option, has_value = word.split("=", 1)[0], "=" in word
            action = parser._option_string_actions.get(option)
            if action is None:
                errors.append(f"'blackbox {' '.join(path)}' has no option {option}")
                continue
            if not has_value and action.nargs != 0:
                index += 1
            continue
        subcommands = _subcommands(parser)
        if subcommands:
            if word not in subcommands:
                errors.append(f"'blackbox {' '.join(path)}' has no subcommand {word!r} "
                              f"(it has {', '.join(sorted(subcommands))})")
                break
            parser = subcommands[word]
            path.append(word)
    return ParsedCommand(tuple(path), tuple(errors))


@pytest.mark.parametrize("command", BLACKBOX, ids=_ids(BLACKBOX))
def test_a_blackbox_command_names_subcommands_and_options_that_exist(
        command: DocCommand) -> None:
    parsed = parse_blackbox(command)
    assert not parsed.errors, f"{command.where}: {command.text}\n" + "\n".join(parsed.errors)
    assert parsed.subcommand, f"{command.where}: {command.text}: no subcommand named"


# --- benchmarks: the script exists and accepts the options -----------------------------------

HELP_OPTION = re.compile(r"(?<![\w-])(--?[A-Za-z][\w-]*)")
HELP_CHOICES = re.compile(r"\{([\w,-]+)\}")


@dataclass(frozen=True)
class ScriptInterface:
    """What a benchmark script's argument parser accepts, read from its ``--help``."""

    options: frozenset[str]
    choices: frozenset[str]


def _help_interface(help_text: str) -> ScriptInterface:
    options: set[str] = set()
    for line in help_text.splitlines():
        invocation = re.match(r"^\s{1,4}(-\S.*?)(\s{2,}|$)", line)
        if invocation:
            options.update(HELP_OPTION.findall(invocation.group(1)))
    usage = help_text.split("\n\n", 1)[0]
    options.update(HELP_OPTION.findall(usage))
    positional_usage = re.sub(r"-[\w-]+\s+\{[^}]*\}", "", usage)  # not an option's choices
    choices = {c for group in HELP_CHOICES.findall(positional_usage) for c in group.split(",")}
    return ScriptInterface(frozenset(options), frozenset(choices))


#: Runs ``benchmarks/SCRIPT [SUBCOMMAND] --help`` for every pair given as JSON, in one
#: interpreter (an interpreter start per script would cost seconds each on this machine),
#: and prints each help text and exit code as JSON. argparse prints the help and exits
#: before a script measures anything. Helper modules the scripts import from the
#: repository's own directories (``support``, two different ``robot`` modules) are
#: forgotten between scripts, as a fresh interpreter would.
HELP_READER = """
import contextlib, io, json, runpy, sys
from pathlib import Path
base = list(sys.path)
local = tuple(str(Path(d).resolve()) for d in ("benchmarks", "scripts", "tests"))
found = {}
for script, sub in json.loads(sys.argv[1]):
    for name, module in list(sys.modules.items()):
        if str(getattr(module, "__file__", None) or "").startswith(local):
            del sys.modules[name]
    sys.argv = [script, *([sub] if sub else []), "--help"]
    sys.path[:] = [str(Path(script).parent), *base]
    text, code = io.StringIO(), None
    try:
        with contextlib.redirect_stdout(text):
            runpy.run_path(script, run_name="__main__")
    except SystemExit as stop:
        code = stop.code
    found[f"{script} {sub or ''}"] = {"code": code, "help": text.getvalue()}
print(json.dumps(found))
"""


def read_helps(pairs: list[tuple[str, str | None]]) -> dict[tuple[str, str | None], str]:
    """The ``--help`` text of each (script, subcommand); a failing one fails the test."""
    if not pairs:
        return {}
    # 25 scripts' imports in one process: ~10 s alone, over 60 s at a load average of 30
    done = subprocess.run([sys.executable, "-c", HELP_READER, json.dumps(pairs)], cwd=ROOT,
                          capture_output=True, text=True, timeout=180, check=False)
    assert done.returncode == 0, f"reading the benchmarks' --help failed:\n{done.stderr}"
    found = json.loads(done.stdout.splitlines()[-1])
    helps = {}
    for script, sub in pairs:
        result = found[f"{script} {sub or ''}"]
        assert result["code"] in (0, None), f"{script} {sub or ''} --help: {result}"
        helps[(script, sub)] = result["help"]
    return helps


def _uses_argparse(script: str) -> bool:
    """A script without argparse takes no options and is never run (it would measure)."""
    return "argparse" in (ROOT / script).read_text(encoding="utf-8")


@cache
def script_interfaces() -> dict[tuple[str, str | None], ScriptInterface]:
    """What every documented benchmark script (and subcommand) accepts."""
    scripts = sorted({c.argv[1] for c in BENCHMARKS if (ROOT / c.argv[1]).is_file()})
    interfaces = {(s, None): ScriptInterface(frozenset(), frozenset()) for s in scripts}
    top = read_helps([(s, None) for s in scripts if _uses_argparse(s)])
    interfaces.update({key: _help_interface(text) for key, text in top.items()})
    subs = sorted({(c.argv[1], c.arguments[0]) for c in BENCHMARKS
                   if (c.argv[1], None) in interfaces and c.arguments
                   and c.arguments[0] in interfaces[(c.argv[1], None)].choices})
    interfaces.update({key: _help_interface(text) for key, text in read_helps(subs).items()})
    return interfaces


def benchmark_errors(command: DocCommand) -> list[str]:
    script = command.argv[1]
    if not (ROOT / script).is_file():
        return [f"no script {script}"]
    interface = script_interfaces()[(script, None)]
    words = [w for w in command.arguments if w]
    positional = [w for w in words if not w.startswith("-")]
    accepted = set(interface.options)
    if interface.choices and positional and positional[0] in interface.choices:
        accepted |= script_interfaces()[(script, positional[0])].options
    elif interface.choices:
        return [f"{script} needs one of {', '.join(sorted(interface.choices))}"]
    return [f"{script} has no option {w.split('=', 1)[0]}" for w in words
            if w.startswith("--") and w.split("=", 1)[0] not in accepted]


@pytest.mark.parametrize("command", BENCHMARKS, ids=_ids(BENCHMARKS))
def test_a_benchmark_command_names_a_script_and_options_it_accepts(
        command: DocCommand) -> None:
    errors = benchmark_errors(command)
    assert not errors, f"{command.where}: {command.text}\n" + "\n".join(errors)


# --- make: the targets exist -----------------------------------------------------------------

def makefile_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text(encoding="utf-8")
    return {m.group(1) for m in re.finditer(r"^([\w.-]+)\s*:(?!=)", text, re.MULTILINE)}


@pytest.mark.parametrize("command", MAKE, ids=_ids(MAKE))
def test_a_make_command_names_targets_of_the_makefile(command: DocCommand) -> None:
    targets = [w for w in command.arguments if "=" not in w and not w.startswith("-")]
    missing = [t for t in targets if t not in makefile_targets()]
    assert targets, f"{command.where}: {command.text}: no target named"
    assert not missing, f"{command.where}: {command.text}: no Makefile target {missing}"


# --- paths inside the repository exist -------------------------------------------------------

def named_paths(command: DocCommand) -> list[str]:
    """Words (and option values after ``=``) that name a path under the repository."""
    paths = []
    for word in command.argv:
        value = _unmark(word.split("=", 1)[1] if word.startswith("-") and "=" in word
                        else word)
        value = re.sub(r"^[a-z][a-z0-9]*:(?!//)", "", value).split("?", 1)[0]
        if value.startswith(("/", "-")) or "://" in value or not value:
            continue
        first = Path(value).parts[0] if Path(value).parts else ""
        if first in REPOSITORY_ROOTS:
            paths.append(value)
    return paths


@pytest.mark.parametrize("command", COMMANDS, ids=_ids(COMMANDS))
def test_every_repository_path_a_command_names_exists(command: DocCommand) -> None:
    missing = [p for p in named_paths(command) if not (ROOT / p).exists()]
    assert not missing, f"{command.where}: {command.text}: no such file {missing}"


# --- the short ones run ----------------------------------------------------------------------

def _needs_absent_file(command: DocCommand) -> bool:
    """True when the command reads a file the reader makes first (``robot.yaml``)."""
    return any(w.endswith(FILE_SUFFIXES) and not (ROOT / w).exists()
               for w in (_unmark(w) for w in command.arguments))


def runnable_here(command: DocCommand) -> bool:
    parsed = parse_blackbox(command)
    synopsis = any(ch in command.text for ch in "[]|")
    return (parsed.subcommand in RUN_HERE and not parsed.errors and not synopsis
            and not _needs_absent_file(command) and not LONG_EXAMPLES & set(command.argv))


RUNNABLE = [c for c in BLACKBOX if runnable_here(c)]


def test_each_short_command_has_a_runnable_example_in_the_docs() -> None:
    shown = {parse_blackbox(c).subcommand for c in RUNNABLE}
    assert shown == RUN_HERE, f"no runnable example of {sorted(RUN_HERE - shown)}"


@pytest.mark.parametrize("command", RUNNABLE, ids=_ids(RUNNABLE))
def test_a_short_command_runs_and_exits_with_0(command: DocCommand,
                                               capsys: pytest.CaptureFixture[str],
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """Run in this process through :func:`blackbox.cli.main`, as the installed script
    does (an interpreter start per command would cost more than the commands)."""
    monkeypatch.chdir(ROOT)
    try:
        code = main(list(command.arguments))
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else 2
    assert code == 0, f"{command.where}: {command.text} exited with {code}:\n" + (
        capsys.readouterr().err[-2000:])


def _command(text: str) -> DocCommand:
    return DocCommand(ROOT / "README.md", 1, text, tuple(shlex.split(text)))


def test_the_checks_catch_a_wrong_command() -> None:
    """The checks above can fail: an unknown option, subcommand, script, target and path."""
    assert parse_blackbox(_command("blackbox log query --db x --kinds failure")).errors
    assert parse_blackbox(_command("blackbox log qurey --db x")).errors
    assert not parse_blackbox(_command("blackbox log query --db x --kind failure")).errors
    assert benchmark_errors(_command(".venv/bin/python benchmarks/no_such.py"))
    assert named_paths(_command("blackbox check-config data/no/such.yaml")) == [
        "data/no/such.yaml"]
    assert "no-such-target" not in makefile_targets()


def test_the_documents_show_commands_of_every_kind() -> None:
    """The extraction itself works: each kind of command is found (a broken pattern would
    otherwise pass every test above by finding nothing)."""
    assert len(BLACKBOX) >= 40 and len(BENCHMARKS) >= 15 and len(MAKE) >= 2, (
        len(BLACKBOX), len(BENCHMARKS), len(MAKE))


# --- links between the documents resolve -----------------------------------------------------

LINK = re.compile(r"\]\(([^)\s]+)\)")


def heading_anchors(document: Path) -> set[str]:
    """GitHub's anchors of a document's headings (lower case, punctuation dropped, spaces
    to hyphens; a repeated heading gets ``-1``, ``-2``, ...) and its ``<a id>`` anchors."""
    anchors: set[str] = set()
    fenced = False
    for line in document.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        anchors.update(re.findall(r'<a id="([^"]+)"></a>', line))
        if fenced or not line.startswith("#"):
            continue
        text = line.lstrip("#").strip().lower()
        slug = re.sub(r"[^\w\- ]", "", text).replace(" ", "-")
        candidate, n = slug, 0
        while candidate in anchors:
            n += 1
            candidate = f"{slug}-{n}"
        anchors.add(candidate)
    return anchors


def broken_links(document: Path) -> list[str]:
    broken = []
    for target in LINK.findall(document.read_text(encoding="utf-8")):
        if re.match(r"^[a-z]+:", target):
            continue  # http(s), mailto: not checked here
        path, _, anchor = target.partition("#")
        file = (document.parent / path).resolve() if path else document
        if not file.exists():
            broken.append(f"{target}: no such file")
        elif anchor and file.suffix == ".md" and anchor not in heading_anchors(file):
            broken.append(f"{target}: no heading with anchor #{anchor}")
    return broken


@pytest.mark.parametrize("document", [*DOCUMENTS, ROOT / "CHANGELOG.md"],
                         ids=lambda d: str(d.relative_to(ROOT)))
def test_every_link_between_documents_resolves(document: Path) -> None:
    assert not broken_links(document), "\n".join(broken_links(document))
