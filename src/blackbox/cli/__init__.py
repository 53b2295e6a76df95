"""The ``blackbox`` command line.

Each subcommand lives in its own module in this package and defines
``register(subparsers) -> None``, which adds its parser and sets ``func`` (a callable taking
the parsed arguments and returning an exit code). The CLI composes library code and holds no
logic of its own.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import signal
import sys
from collections.abc import Sequence

from blackbox import __version__
from blackbox.errors import BlackBoxError
from blackbox.terminate import EXIT_TERMINATED, Terminated, raise_terminated

EXIT_USAGE = 2


def command_module(argv: Sequence[str]) -> str | None:
    """The module of the subcommand ``argv`` names (``check-config`` -> ``check_config``),
    or None when it names none (``--help``, ``--version``, a typo).

    Building the parser imports every command's module, and with them numpy, scipy,
    Cyclone DDS and the learner: about a second of CPU at each start. A command needs only
    its own module, which matters where ``blackbox`` processes start often (tests, scripts,
    a supervisor restarting ``run``)."""
    for arg in argv:
        if arg.startswith("-"):
            return None  # options before the command: the full parser answers them
        name = arg.replace("-", "_")
        known = {info.name for info in pkgutil.iter_modules(__path__)
                 if not info.name.startswith("_")}
        return name if name in known else None
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``blackbox`` parser with every command, or with command module ``only`` alone
    (:func:`command_module`): that command parses, prints its help and its errors as in
    the full parser."""
    parser = argparse.ArgumentParser(
        prog="blackbox",
        description="Robot black box: watch a robot, detect and isolate faults, record its health.",
    )
    parser.add_argument("--version", action="version", version=f"blackbox {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_") or (only is not None and info.name != only):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    arguments = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(command_module(arguments))
    args = parser.parse_args(arguments)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        # Before any file is read: a SIGTERM while a configuration loads ends the command
        # at once, through its ``finally`` blocks. Commands that run (``run``, ``station``)
        # install their own handlers for a graceful stop once they are set up.
        signal.signal(signal.SIGTERM, raise_terminated)
    try:
        return int(args.func(args) or 0)
    except Terminated:
        print("terminated", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(EXIT_TERMINATED)  # unwound already; skip the interpreter's slow teardown
    except BlackBoxError as exc:  # ConfigError, StorageError, RequestAuthError, ...
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
